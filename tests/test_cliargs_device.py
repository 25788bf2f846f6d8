"""``--device`` and ``--twin-set`` mean the same in every command: one declaration, one default,
one parser of the twin's hidden settings (:mod:`twin.cliargs`)."""

from __future__ import annotations

import argparse

import pytest

from twin.cli import build_parser
from twin.cliargs import DEFAULT_DEVICE, UsageError, twin_params
from twin.params import load_params


def _parsers(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, (*path, name))


def _option(parser: argparse.ArgumentParser, option: str) -> argparse.Action | None:
    return next((a for a in parser._actions if option in a.option_strings), None)


def test_every_device_option_defaults_to_the_twin_or_to_none_and_takes_every_scheme():
    found = {}
    for path, parser in _parsers(build_parser()):
        device = _option(parser, "--device")
        if device is not None:
            found[" ".join(path)] = device
        twin_set = _option(parser, "--twin-set")
        if twin_set is not None:
            assert device is not None, f"twin {' '.join(path)}: --twin-set without --device"
            assert twin_set.dest == "twin_overrides" and isinstance(twin_set, argparse._AppendAction)
    # validate, stiffness, calibrate, dynamics record, compensate, cocontraction, discrepancy at least.
    assert len(found) >= 7, sorted(found)
    for command, action in found.items():
        assert action.metavar == "URL", command
        # None only where the command runs on a device just when given one (discrepancy).
        assert action.default in (DEFAULT_DEVICE, None), f"twin {command}: --device default {action.default!r}"
    assert sum(a.default is None for a in found.values()) == 1


def _args(device, *overrides):
    return argparse.Namespace(device=device, twin_overrides=list(overrides))


def test_twin_set_changes_the_twin_on_sim_only_and_names_what_it_refuses():
    params = load_params()
    assert twin_params(_args("sim://"), params) is params
    hidden = twin_params(_args("sim://?seed=2", "effects.tendon_friction_coeff=0.3"), params)
    assert hidden.get("effects.tendon_friction_coeff") == pytest.approx(0.3)
    assert params.get("effects.tendon_friction_coeff") != pytest.approx(0.3)
    with pytest.raises(UsageError, match=r"^--twin-set effects.tendon_friction_coeff=0.3: applies to sim:// only, "
                                         r"not --device socket://127.0.0.1:7000$"):
        twin_params(_args("socket://127.0.0.1:7000", "effects.tendon_friction_coeff=0.3"), params)
    with pytest.raises(UsageError, match=r"^--twin-set: .*no_such_key"):
        twin_params(_args("sim://", "effects.no_such_key=1"), params)
