"""The firmware's compiled defaults (firmware/core/config.h) are the parameter set's values."""

import ast
import operator
import re
import shutil
import subprocess

import pytest

from twin import load_params
from twin.device.firmware_lib import FIRMWARE_DIR

CONFIG = (FIRMWARE_DIR / "core" / "config.h").read_text()
PARAMS = load_params()


_OPERATORS = {ast.Mult: operator.mul, ast.Div: operator.truediv}


def _value(node: ast.expr) -> float:
    if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)):
        return float(node.value)
    if isinstance(node, ast.BinOp) and type(node.op) in _OPERATORS:
        return _OPERATORS[type(node.op)](_value(node.left), _value(node.right))
    raise AssertionError(f"{ast.unparse(node)}: not a product or quotient of numbers")


def constant(name: str) -> float:
    """The value of ``constexpr <type> <name> = <expression>;`` in config.h, where the expression
    multiplies or divides number literals (``1.0f / 45000.0f``, ``4.0 * 1024.0``)."""
    match = re.search(rf"constexpr\s+\w+\s+{name}\s*=\s*([^;]+);", CONFIG)
    assert match, f"{name} is not in config.h"
    expression = re.sub(r"(\d)f\b", r"\1", match.group(1))
    return _value(ast.parse(expression, mode="eval").body)


@pytest.mark.parametrize("name, expected", [
    ("kEncoderCountsPerMotorRev", PARAMS.rig.encoder_counts_per_rev),
    ("kGearRatio", PARAMS.rig.gear_ratio),
    ("kSpoolRadiusM", PARAMS.rig.spool_radius_m),
    ("kControlPeriodUs", 1e6 / PARAMS.rig.control_rate_hz),
    ("kTelemetryPeriodUs", 1e6 / PARAMS.rig.telemetry_rate_hz),
    ("kLoadcellPeriodUs", 1e6 / PARAMS.rig.loadcell_rate_hz),
    ("kDefaultTensionLimitN", PARAMS.rig.tension_limit_n),
    ("kDefaultGainNPerCount", 1.0 / PARAMS.sensors.loadcell_gain_counts_per_n),
    ("kDefaultChannels", PARAMS.tendons.count),
    ("kMotorStallTorqueNm", PARAMS.rig.motor_stall_torque_nm),
    ("kMotorNoLoadSpeedRpm", PARAMS.rig.motor_no_load_speed_rpm),
    ("kMotorRotorInertiaKgm2", PARAMS.rig.motor_rotor_inertia_kgm2),
])
def test_a_compiled_default_is_the_parameter_sets_value(name, expected):
    assert constant(name) == pytest.approx(expected, rel=1e-12)


def test_the_parser_reads_what_it_claims():
    # A constant that is not there, or not a number, is a failure rather than a silent pass.
    with pytest.raises(AssertionError):
        constant("kNoSuchConstant")
    assert constant("kMaxTensionLimitN") == 50.0


def test_the_driver_refuses_what_the_firmware_refuses():
    from twin.driver import device

    assert device.GAIN_TOLERANCE == constant("kGainTolerance")
    low, high = device.RATED_GAIN_COUNTS_PER_N
    assert low == constant("kMinRatedGainCountsPerN")
    # config.h computes it from the other constants; the driver's must be the same number.
    assert high == pytest.approx((constant("kLoadcellMaxCounts") - constant("kMaxOffsetCounts"))
                                 / (constant("kMaxTensionLimitN") * constant("kGainTolerance")), rel=1e-7)
    assert device.MAX_OFFSET_COUNTS == constant("kMaxOffsetCounts")
    assert device.MAX_TENSION_LIMIT_N == constant("kMaxTensionLimitN")
    assert device.MAX_LENGTH_SETPOINT_M == pytest.approx(constant("kMaxLengthSetpointM"), rel=1e-7)


def test_the_motors_bounds_and_defaults_are_the_firmwares():
    from twin.board_limits import MOTOR_BOUNDS
    from twin.driver.codec import SetMotors

    firmware_names = {"stall_force_n": "StallForceN", "no_load_speed_m_per_s": "NoLoadSpeedMPerS",
                      "reflected_mass_kg": "ReflectedMassKg"}
    for name, (_, low, high) in MOTOR_BOUNDS.items():
        assert (low, high) == pytest.approx((constant(f"kMin{firmware_names[name]}"),
                                             constant(f"kMax{firmware_names[name]}")), rel=1e-7), name
    # The board's defaults until the host sends its motors are the thesis rig's, as the host
    # derives them from the parameter set.
    default = SetMotors()
    assert default.stall_force_n == pytest.approx(PARAMS.rig.motor_stall_force_n, rel=1e-12)
    assert default.no_load_speed_m_per_s == pytest.approx(PARAMS.rig.motor_no_load_speed_m_per_s, rel=1e-12)
    assert default.reflected_mass_kg == pytest.approx(PARAMS.rig.motor_reflected_mass_kg, rel=1e-12)


PINS = FIRMWARE_DIR / "teensy" / "twin_rig" / "pins.h"


def _compile_pins(text: str, tmp_path) -> subprocess.CompletedProcess:
    header = tmp_path / "pins.h"
    header.write_text(text)
    return subprocess.run(["g++", "-std=gnu++14", "-fsyntax-only", "-x", "c++", str(header)],
                          capture_output=True, text=True, check=False)


@pytest.mark.skipif(shutil.which("g++") is None, reason="needs g++")
def test_the_teensy_pin_map_wires_eight_motors_each_pin_once(tmp_path):
    text = PINS.read_text()
    assert _compile_pins(text, tmp_path).returncode == 0
    tables = {name: [int(p) for p in values.split(",")]
              for name, values in re.findall(r"constexpr uint8_t (k\w+)\[kMotors\] = \{([^}]*)\};", text)}
    assert set(tables) == {"kMotorIn1", "kMotorIn2", "kEncoderA", "kEncoderB", "kLoadcellDout", "kLoadcellSck"}
    pins = [p for values in tables.values() for p in values]
    assert all(len(values) == 8 for values in tables.values())
    assert len(set(pins)) == len(pins) and 13 not in pins and all(0 <= p <= 57 for p in pins)
    # The checks in the header are real: a pin wired twice, or a motor off PWM, does not compile.
    twice = text.replace("kLoadcellSck[kMotors] = {16,", "kLoadcellSck[kMotors] = {15,")
    assert "wired twice" in _compile_pins(twice, tmp_path).stderr
    off_pwm = text.replace("kMotorIn2[kMotors] = {3,", "kMotorIn2[kMotors] = {13,")
    assert "not on a PWM pin" in _compile_pins(off_pwm, tmp_path).stderr
    # The rig's count is the parameter set's.
    assert re.search(r"kRigChannels = (\d+);", text).group(1) == str(PARAMS.tendons.count)
