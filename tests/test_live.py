"""The live browser view (twin.live): it draws what it is shown, off the caller's thread, and a
real headless Chromium shows the backbone on the page."""

from __future__ import annotations

import shutil
import subprocess
import time

import matplotlib.image
import numpy as np
import pytest

pytest.importorskip("viser", reason="the live view needs viser (pip install 'twin[live]')")

from twin.live import COLORS, LiveDevice, LiveView, show_twin  # noqa: E402
from twin.params import load_params  # noqa: E402
from twin.rod.grid import pcc_tensions_n  # noqa: E402

PARAMS = load_params()


@pytest.fixture(scope="module")
def bent_plant():
    from twin.sim.plant import Plant

    plant = Plant(PARAMS, base_rotation=PARAMS.rig.base_rotation)
    plant.set_tensions(pcc_tensions_n(20.0, 0.0, PARAMS))
    plant.settle()
    return plant


def test_show_returns_at_once_and_the_view_predicts_the_shown_tensions(bent_plant):
    with LiveView(PARAMS) as view:
        assert view.url.startswith("http://127.0.0.1:") and not view.url.endswith(":0/")
        start = time.perf_counter()
        show_twin(view, bent_plant, label="bent")
        assert time.perf_counter() - start < 0.05  # drawing and the solve happen on the view's thread
        assert view.wait_drawn(1, timeout_s=60.0)
        predicted = view._handles["predicted"].points
        measured = bent_plant.backbone_positions_m()
        # The predictor's tip for the twin's true tensions lands near the twin's tip (crosscheck: < 3% of L).
        assert np.linalg.norm(predicted[-1] - measured[-1]) < 0.03 * PARAMS.backbone.length_m
        assert np.allclose(view._handles["measured"].points, measured)


def test_states_shown_faster_than_the_rate_are_skipped_not_queued():
    with LiveView(PARAMS, rate_hz=2.0, predict=False) as view:
        for k in range(50):
            view.show(tip_m=np.array([0.001 * k, 0.0, 0.0]))
        assert view.wait_drawn(1, timeout_s=10.0)
        time.sleep(1.0)
        assert view.draws <= 3
        assert np.allclose(view._handles["tip"].position, [0.049, 0.0, 0.0])  # the newest state


def test_a_watched_device_shows_what_its_user_reads_and_the_twin():
    from twin.driver import open_device

    with open_device("sim://", params=PARAMS, seed=1) as device, LiveView(PARAMS, predict=False) as view:
        device.connect()
        watched = LiveDevice(device, view)
        assert watched.url == device.url  # everything else is the device's
        watched.wait(0.1)
        sample = watched.latest()
        assert view.wait_drawn(1, timeout_s=10.0)
        frame = watched.tracker.read()
        assert frame.pose is not None
        time.sleep(0.6)  # past the throttle
        drawn = view.draws
        watched.wait(0.01)
        assert view.wait_drawn(drawn + 1, timeout_s=10.0)
        assert np.allclose(view._handles["measured"].points, device.twin.backbone_positions_m(), atol=1e-7)
        assert np.allclose(view._handles["tip"].position, frame.pose.position_m)
        assert sample.tensions_n.shape == (4,)


# --------------------------------------------------------------------------- in a browser
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--disable-quic",
                  "--no-first-run", "--disable-background-networking", "--disable-component-update",
                  "--disable-sync", "--hide-scrollbars"]


def _chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    pytest.skip("no Chromium on PATH (scripts/test.sh installs Debian's chromium when it runs as root)")


def _screenshot(url: str, folder, *, shown: str, settle_s: float = 3.0) -> np.ndarray:
    """(H, W, 3) uint8 of the page at ``url`` in headless Chromium, ``settle_s`` of real time after
    the text ``shown`` (a label the view was shown) is on the page: the scene comes over the
    websocket after the load event, with the panel's text. Driven over the DevTools protocol:
    ``--screenshot`` shoots at the load event, and its virtual time starves the websocket."""
    import base64
    import json
    import urllib.request

    from websockets.sync.client import connect

    folder.mkdir(parents=True)
    profile = folder / "profile"
    browser = subprocess.Popen([_chromium(), *CHROMIUM_FLAGS, f"--user-data-dir={profile}", "--window-size=1000,700",
                                "--remote-debugging-address=127.0.0.1", "--remote-debugging-port=0", "about:blank"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        port_file = profile / "DevToolsActivePort"
        deadline = time.monotonic() + 60.0
        while not port_file.exists() or not port_file.read_text().strip():
            assert browser.poll() is None and time.monotonic() < deadline, "Chromium did not start"
            time.sleep(0.1)
        port = int(port_file.read_text().split()[0])
        pages = json.loads(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10).read())
        target = next(p["webSocketDebuggerUrl"] for p in pages if p["type"] == "page")
        with connect(target, max_size=None, open_timeout=30) as cdp:
            ids = iter(range(1, 1000))

            def call(method: str, **params):
                key = next(ids)
                cdp.send(json.dumps({"id": key, "method": method, "params": params}))
                while True:
                    message = json.loads(cdp.recv(timeout=120))
                    if message.get("id") == key:
                        assert "error" not in message, message
                        return message["result"]

            call("Page.enable")
            call("Emulation.setDeviceMetricsOverride", width=1000, height=700, deviceScaleFactor=1, mobile=False)
            call("Page.navigate", url=url)
            deadline = time.monotonic() + 120.0
            probe = f"document.body !== null && document.body.innerText.includes({json.dumps(shown)})"
            while not call("Runtime.evaluate", expression=probe)["result"].get("value"):
                assert time.monotonic() < deadline, f"the page never showed {shown!r}"
                time.sleep(0.5)
            time.sleep(settle_s)
            data = call("Page.captureScreenshot", format="png")["data"]
    finally:
        browser.terminate()
        browser.wait(timeout=30)
    shot = folder / "page.png"
    shot.write_bytes(base64.b64decode(data))
    return (matplotlib.image.imread(shot)[..., :3] * 255).astype(np.uint8)


def _backbone_mask(pixels: np.ndarray) -> np.ndarray:
    """Pixels of the measured backbone's hue (lit, so brighter than its colour): red above green
    above blue, well apart."""
    r, g, b = (pixels[..., i].astype(int) for i in range(3))
    red, green, blue = COLORS["measured"]
    assert red > green > blue
    return (r > g + 20) & (g > b + 20) & (r - b > 60)


@pytest.mark.slow
def test_the_page_shows_the_bent_backbone_in_headless_chromium(bent_plant, tmp_path):
    tensions = bent_plant.true_tensions_n()
    with LiveView(PARAMS, predict=False) as empty, LiveView(PARAMS, predict=False) as bent:
        empty.show(tensions_n=tensions, label="same label")
        show_twin(bent, bent_plant, label="same label")
        assert empty.wait_drawn(1) and bent.wait_drawn(1)
        without = _screenshot(empty.url, tmp_path / "without", shown="same label")
        with_backbone = _screenshot(bent.url, tmp_path / "with", shown="same label")
    assert without.shape == with_backbone.shape == (700, 1000, 3)
    assert with_backbone.std() > 10  # not a blank page
    # The same page (legend, tension bars) but for the backbone: its colour appears where it is drawn.
    drawn = _backbone_mask(with_backbone) & ~_backbone_mask(without)
    assert drawn.sum() > 1000, (drawn.sum(), _backbone_mask(without).sum())
    # ... as a bent rod: across and well down the page (straight and horizontal, it would be a
    # band a few pixels high).
    ys, xs = np.nonzero(drawn)
    assert xs.max() - xs.min() > 80 and ys.max() - ys.min() > 50, (xs.min(), xs.max(), ys.min(), ys.max())


def test_the_env_with_live_port_shows_its_episode_without_changing_it():
    from twin.envs.reach import EndoscopeReachEnv

    target = np.array([0.05, 0.0, -0.02])
    runs = []
    for live_port in (None, 0):
        env = EndoscopeReachEnv(live_port=live_port)
        try:
            observation, _ = env.reset(seed=3, options={"target_m": target, "tip_mass_kg": 0.0})
            steps = [env.step(np.full(env.action_space.shape, 0.2, np.float32))[0] for _ in range(3)]
            runs.append(np.vstack([observation, *steps]))
            if live_port is not None:
                assert env.live_url.startswith("http://127.0.0.1:")
                view = env._live
                assert view.wait_drawn(1, timeout_s=30.0)
                time.sleep(0.5)
                env.step(np.zeros(env.action_space.shape, np.float32))
                assert view.wait_drawn(2, timeout_s=30.0)
                assert np.allclose(view._handles["target"].position, target)
                assert view._handles["measured"].visible
        finally:
            env.close()
    assert np.array_equal(runs[0], runs[1])  # watching adds no command, ping or tracker sample


def test_without_live_the_commands_do_not_load_the_viewer():
    import subprocess
    import sys

    code = ("import sys; from twin.cli import main; "
            "code = main(['sim', '--tensions', '2,1.35,1.35,1.35', '--json']); "
            "print('viser' in sys.modules, code)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True)
    assert out.stdout.split()[-2:] == ["False", "0"], out.stdout


@pytest.mark.parametrize("command", [["sim", "--tensions", "2.5,1.35,1.35,1.35"], ["emulate"]])
def test_live_serves_the_page_and_prints_its_url(command):
    import signal
    import subprocess
    import sys
    import urllib.request

    # SIGINT restored to its default in the child: one started while another thread of this
    # process is inside system(3) inherits it ignored (seen under pytest-xdist), and then no
    # Ctrl-C reaches it.
    process = subprocess.Popen([sys.executable, "-m", "twin.cli", *command, "--live"], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 120.0
        url = None
        while url is None and time.monotonic() < deadline:
            line = process.stderr.readline()
            assert line or process.poll() is None, "the command ended before serving"
            if "live view at " in line:
                url = line.split("live view at ")[1].strip()
        assert url is not None and url.startswith("http://127.0.0.1:")
        page = urllib.request.urlopen(url, timeout=30).read().decode()
        assert "<html" in page.lower()
    finally:
        process.send_signal(signal.SIGINT if command[0] == "sim" else signal.SIGTERM)
        process.communicate(timeout=60)
    assert process.returncode == 0
