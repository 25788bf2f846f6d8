"""A host that only talks to the rig needs neither MuJoCo nor a C++ compiler.

The check runs in a fresh interpreter whose imports of ``mujoco`` fail and whose ``PATH`` holds
no compiler: it imports the rig driver (:mod:`twin.driver`), opens a ``serial://`` device on a
pseudo-terminal (a board played by hand answers), and fuses a tracker frame; nothing of the twin's
rooms (``twin.sim``, ``twin.device``) is loaded.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np

from twin.pose import quat_to_matrix
from twin.tracking import CapCalibration, FusionSettings, ProbeFrame, ProbeReading, fuse_frame

HOST_WITHOUT_MUJOCO = textwrap.dedent("""
    import json, os, sys, threading, tty

    class NoMujoco:
        def find_spec(self, name, path=None, target=None):
            if name.partition(".")[0] == "mujoco":
                raise ImportError(f"{name}: not installed on this host")
            return None

    sys.meta_path.insert(0, NoMujoco())

    import twin.driver
    import twin.driver.serial_transport
    from twin.driver import codec as c, open_device
    from twin.tracking import CapCalibration, FusionSettings, ProbeFrame, ProbeReading, fuse_frame

    from twin import load_params

    # The board counts as the default robot's rig does (the host refuses one that counts otherwise).
    M_PER_COUNT = load_params().rig.tendon_m_per_count
    master, slave = os.openpty()
    tty.setraw(slave)

    def board():
        decoder = c.FrameDecoder()
        while True:
            try:
                data = os.read(master, 4096)
            except OSError:
                return
            for frame in decoder.feed(data):
                if isinstance(frame.message, c.Hello):
                    os.write(master, c.encode_frame(c.HelloReply(tendon_m_per_count=M_PER_COUNT), seq=0))
                else:
                    # The host waits for a sample after the DISABLE it sends on connecting.
                    os.write(master, c.encode_frame(c.Ack(acked_seq=frame.seq, acked_type=frame.message.TYPE), seq=2)
                             + c.encode_frame(c.TelemetryMessage(sample_seq=7, lengths_m=(1e-3, 0.0, -1e-3, 0.0),
                                                                 state=c.State.ENABLED), seq=1))

    threading.Thread(target=board, daemon=True).start()
    device = open_device(f"serial://{os.ttyname(slave)}")
    device.connect(timeout_s=2.0)
    sample = device.latest()
    device.close()

    rows = json.loads(sys.argv[1])
    fused = fuse_frame(ProbeFrame(ProbeReading(*rows[0]), ProbeReading(*rows[1]), rows[2]), CapCalibration(),
                       FusionSettings())
    loaded = sorted(m for m in sys.modules if m.partition(".")[0] == "mujoco" or m.startswith(
        ("twin.sim", "twin.device")))
    print(json.dumps({"seq": sample.seq, "lengths_m": sample.tendon_lengths_m.tolist(), "ok": fused.ok,
                      "position_m": fused.pose.position_m.tolist(), "rotation": fused.pose.rotation.tolist(),
                      "loaded": loaded}))
""")


def _probe_rows(rotation, position_m, cal=CapCalibration(), t_s=1.0):
    rows = []
    for offset, axis in ((cal.position_a_m, cal.axis_a), (cal.position_b_m, cal.axis_b)):
        rows.append([(position_m + rotation @ np.asarray(offset)).tolist(), (rotation @ np.asarray(axis)).tolist(), t_s])
    return rows + [t_s]


def test_device_serial_and_tracker_fusion_work_without_mujoco_or_a_compiler(tmp_path):
    rotation = quat_to_matrix(np.array([0.9, 0.1, -0.3, 0.2]))
    rows = _probe_rows(rotation, np.array([0.01, -0.02, 0.05]))
    # An empty PATH: no g++ to build the firmware or the native plant loop with. The timeout only
    # catches a hang: a fresh HOME compiles the fusion's Numba kernels, which a loaded CI box took
    # more than a minute for.
    run = subprocess.run([sys.executable, "-c", HOST_WITHOUT_MUJOCO, json.dumps(rows)], capture_output=True,
                         text=True, timeout=240, env={"PATH": str(tmp_path), "HOME": str(tmp_path)})
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    assert out["loaded"] == []
    assert out["seq"] == 7
    np.testing.assert_allclose(out["lengths_m"], [1e-3, 0.0, -1e-3, 0.0], atol=1e-9)
    # Without MuJoCo the fusion gives what it gives here.
    here = fuse_frame(ProbeFrame(ProbeReading(*rows[0]), ProbeReading(*rows[1]), rows[2]), CapCalibration(),
                      FusionSettings())
    assert out["ok"] and here.ok
    np.testing.assert_allclose(out["position_m"], here.pose.position_m, atol=1e-12)
    np.testing.assert_allclose(out["rotation"], here.pose.rotation, atol=1e-12)
    np.testing.assert_allclose(out["rotation"], rotation, atol=1e-9)
