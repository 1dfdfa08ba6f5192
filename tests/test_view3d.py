"""The 3D views (analysis.scene, analysis.replay, analysis.region_volumes --view): the page is
MeshCat's own export, the replay is the policy's episodes, bad run folders are named, and a real
browser draws the arm and plays the animation."""

from __future__ import annotations

import io
import json
import shutil
import time

import numpy as np
import pytest
from cli_tools import ROOT, run_module

meshcat = pytest.importorskip("meshcat", reason="the 3D views need meshcat: pip install -e "
                              "'.[view]' (bash dev.sh test installs it)")

import regions  # noqa: E402
import ur5kin  # noqa: E402
from analysis import replay, scene  # noqa: E402

pytestmark = pytest.mark.xdist_group("test_view3d")
"""Under pytest-xdist one worker runs this module, so that the replayed page (`replayed`) is made
once."""


@pytest.fixture(scope="module")
def replayed(tiny_ur5_run):
    """The tiny run's policy replayed on 2 goals: (task, episodes, page path)."""
    import ddpg_her

    policy = ddpg_her.load(tiny_ur5_run)
    task, episodes = replay.rollout(policy, replay.episode_seeds(0, 2), progress=False)
    page = tiny_ur5_run.parent / "replay.html"
    view = scene.Scene(scene.offline_visualizer(), task.base_height)
    replay.draw(view, task, episodes, "collision")
    view.write_html(page, "test replay", "caption")
    return task, episodes, page


def _commands(window: scene.RecordingWindow) -> list[dict]:
    import umsgpack

    return [umsgpack.unpackb(c) for c in window.commands()]


# --- the page --------------------------------------------------------------------------------
def _small_scene(window=None) -> scene.Scene:
    """A scene with one of each drawing, an animation, and the commands whose bookkeeping
    matters: an object replaced after a property, a deleted subtree."""
    vis = scene.offline_visualizer() if window is None else meshcat.Visualizer(window=window)
    view = scene.Scene(vis, 0.1)
    view.setup()
    view.ground()
    view.region(regions.get("farbox"), "region", scene.REGION_COLOURS[0][0])
    arm = view.arm("arm", regions.CONSTRAINED_START)
    view.goal("goals/0", [0.7, 0.0, 0.2], 0.1, True)
    view.goal("goals/1", [0.7, 0.2, 0.2], 0.1, False)
    view.vis["goals/1"].delete()
    view.vis["goals/0/dot"].set_property("visible", False)
    view.marker("goals/0/dot", [0.0, 0.0, 0.0], scene.START_COLOUR)  # drops the property
    timeline = scene.Timeline(50)
    q = np.tile(regions.CONSTRAINED_START, (5, 1))
    q[:, 0] = np.linspace(0.0, 0.4, 5)
    timeline.poses(view.vis, arm, 0, q)
    timeline.visible(view.vis, "goals/0", 0, False)
    timeline.visible(view.vis, "goals/0", 3, True)
    timeline.play(view.vis)
    return view


class _Tee:
    """A MeshCat window that hands every command to several windows."""

    def __init__(self, *windows) -> None:
        self.windows = windows

    def send(self, command) -> None:
        for window in self.windows:
            window.send(command)


def test_the_offline_page_is_meshcats_own_static_html():
    """Two paths: the page our recorder writes, and the page a real MeshCat server returns
    for static_html(), each having received the same commands."""
    import zmq

    try:
        live = scene.live_visualizer()
    except (OSError, zmq.ZMQError, RuntimeError) as err:  # pragma: no cover
        pytest.skip(f"no local MeshCat server: {err}")
    try:
        recorder = scene.RecordingWindow()
        _small_scene(_Tee(recorder, live.window))
        assert scene.meshcat_page(recorder.commands()) == live.static_html()
    finally:
        live.window.server_proc.kill()
        live.window.server_proc.wait()


def test_the_recorder_keeps_what_meshcats_server_keeps():
    view = _small_scene()
    window = view.vis.window
    before = len(window.commands())
    view.vis["goals/0"].set_transform(np.eye(4))  # replaces the node's transform
    assert len(window.commands()) == before
    view.vis["goals/0"].delete()                  # drops the subtree: the node, ball and dot
    paths = [c["path"] for c in _commands(window)]
    assert not any(p.startswith("/meshcat/goals/0") for p in paths)
    assert any(p.startswith("/meshcat/arm/") for p in paths)


def test_the_page_embeds_every_mesh_and_needs_no_network(replayed):
    _, _, page = replayed
    text = page.read_text()
    assert 0.5e6 < len(text) < 3e6, len(text)  # the viewer's script is 0.84 MB
    assert "http://" not in text.replace("http://www.w3.org", "")  # no fetch but data: URLs
    assert "fetch(\"data:application/octet-binary;base64," in text
    commands = _commands_of_page(text)
    parts = [c for c in commands if c["type"] == "set_object" and c["path"].startswith(
        "/meshcat/arm/")]
    assert len(parts) == len(ur5kin.mesh_parts("collision"))


def _commands_of_page(text: str) -> list[dict]:
    import base64
    import re

    import umsgpack

    blobs = re.findall(r'fetch\("data:application/octet-binary;base64,([^"]+)"\)', text)
    return [umsgpack.unpackb(base64.b64decode(b)) for b in blobs]


# --- the replay ------------------------------------------------------------------------------
def test_the_replay_is_the_policys_episodes(replayed, tiny_ur5_run):
    """The recorded tool positions are ur5kin's FK of the recorded joint angles (env vs
    kinematics), goals lie in the task's region, outcomes follow the success radius, and the
    same seed replays the same episodes."""
    import ddpg_her

    task, episodes, _ = replayed
    region = regions.parse(task.region, task.base_height)
    for ep in episodes:
        np.testing.assert_allclose(ep.tool, ur5kin.fk_world(ep.q, task.base_height), atol=1e-9)
        assert region.contains(ep.goal)
        assert ep.reached == bool(np.linalg.norm(ep.tool[-1] - ep.goal) <= task.success_radius)
        assert 1 <= ep.steps <= task.max_episode_steps
    again = replay.rollout(ddpg_her.load(tiny_ur5_run), replay.episode_seeds(0, 2), False)[1]
    for a, b in zip(episodes, again, strict=True):
        np.testing.assert_array_equal(a.q, b.q)


def test_the_animation_runs_at_the_control_rate_through_every_step(replayed):
    task, episodes, page = replayed
    commands = _commands_of_page(page.read_text())
    (animation,) = [c for c in commands if c["type"] == "set_animation"]
    clips = {a["path"]: a["clip"] for a in animation["animations"]}
    part = f"/meshcat/arm/{ur5kin.mesh_parts('collision')[2].name}"  # the upper arm
    assert clips[part]["fps"] == task.control_hz == 50
    (position,) = [t for t in clips[part]["tracks"] if t["name"] == ".position"]
    times = [k["time"] for k in position["keys"]]
    hold = round(replay.HOLD_S * task.control_hz)
    frames = sum(ep.steps + 1 for ep in episodes) + len(episodes)  # + one hold key each
    assert len(times) == frames and times == sorted(times)
    assert times[-1] == sum(ep.steps + hold + 1 for ep in episodes) - 1
    poses = ur5kin.part_poses(episodes[0].q, "collision")[:, 2]
    np.testing.assert_allclose([k["value"] for k in position["keys"][: episodes[0].steps + 1]],
                               poses[:, :3, 3], atol=1e-12)
    goal_clip = clips["/meshcat/goals/001"]
    (visible,) = goal_clip["tracks"]
    assert [(k["time"], k["value"]) for k in visible["keys"]] == \
        [(0, False), (episodes[0].steps + hold + 1, True)]


def _run_replay(*argv: str, capsys) -> tuple[int, str]:
    with pytest.raises(SystemExit) as exit_info:
        replay.main(list(argv))
    return exit_info.value.code, capsys.readouterr().err


def test_bad_run_folders_get_an_error_naming_the_folder(tmp_path, tiny_ur5_run, capsys):
    no_weights = tmp_path / "eval_only"
    no_weights.mkdir()
    shutil.copy(ROOT / "results" / "farbox_j3_k5" / "s0" / "spec.json", no_weights)
    code, err = _run_replay(str(no_weights), "--out", str(tmp_path / "x.html"), capsys=capsys)
    assert code == 2 and str(no_weights) in err and "no checkpoint" in err

    other_env = tmp_path / "toy"
    shutil.copytree(tiny_ur5_run, other_env)
    spec = json.loads((other_env / "spec.json").read_text())
    (other_env / "spec.json").write_text(json.dumps({**spec, "env_id": "ToyGoal-v0"}))
    code, err = _run_replay(str(other_env), capsys=capsys)
    assert code == 2 and str(other_env) in err and "'ToyGoal-v0'" in err

    for missing in (tmp_path / "nothing", tmp_path):
        code, err = _run_replay(str(missing), capsys=capsys)
        assert code == 2 and str(missing) in err
    code, err = _run_replay(str(tiny_ur5_run), "--episodes", "0", capsys=capsys)
    assert code == 2 and "--episodes" in err
    assert not (tmp_path / "x.html").exists()


def test_the_cli_writes_the_page(tiny_ur5_run, tmp_path):
    out = tmp_path / "replay.html"
    done = run_module("analysis.replay", str(tiny_ur5_run), "--episodes", "1", "--out", str(out),
                      "--no-progress")
    assert "0 of 1 goals reached" in done.stdout or "1 of 1 goals reached" in done.stdout
    assert out.stat().st_size > 0.5e6
    assert "episode 2" in out.read_text()  # the caption names the checkpoint


def test_region_volumes_view_draws_each_region_and_start(tmp_path):
    from analysis import region_volumes

    out = tmp_path / "regions.html"
    settings = region_volumes.Settings(regions=("farbox", "zheight", "zmax:0.3"))
    region_volumes.view(settings, out)
    commands = _commands_of_page(out.read_text())
    objects = {c["path"] for c in commands if c["type"] == "set_object"}
    for name in ("farbox", "zheight", "zmax:0.3"):
        assert f"/meshcat/regions/{regions.parse(name).name}/faces" in objects
    # zheight and zmax:0.3 share the constrained start with farbox: one arm
    starts = {p.split("/")[3] for p in objects if p.startswith("/meshcat/starts/")}
    assert starts == {"constrained", "constrained_tool0"}
    # a bare z-limit (unbounded, no mesh of its own) is drawn cut to the reach ball, as
    # regions.parse cuts zmax:Z
    slab = scene.region_mesh(regions.ZLimit(0.0, 0.3, name="slab"), 0.1)
    cut = regions.parse("zmax:0.3").mesh
    assert slab.is_watertight and slab.volume == pytest.approx(cut.volume)
    np.testing.assert_allclose(slab.bounds, cut.bounds)


# --- a real browser --------------------------------------------------------------------------
def _pixels(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int16)


def _changed(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs(a - b).max(axis=-1) > 24


def _inside(mask: np.ndarray, boxes) -> int:
    keep = np.zeros_like(mask)
    for x0, y0, x1, y1 in boxes:
        keep[y0:y1, x0:x1] = True
    return int((mask & keep).sum())


def test_a_browser_draws_the_arm_and_plays_the_replay(replayed):
    """Headless Chromium opens the page. The arm is drawn: hiding it changes pixels where it
    is and nowhere else. The animation plays: from reset (the start pose), the viewer's play
    control advances it in real time, and the frame it is paused at differs from the first
    where the arm is. (Paused for each screenshot: a software-rendered screenshot takes about
    0.5 s on a loaded machine, longer than the untrained policy's whole move.)"""
    from benchmarks.browser import Browser, BrowserError, ViewerPage, find_chromium

    if find_chromium() is None:
        pytest.skip("no Chromium for the browser test: apt-get install chromium (bash dev.sh "
                    "test installs it when run as root on Debian or Ubuntu)")
    _, episodes, page = replayed
    moved_by = np.abs(episodes[0].q[10] - episodes[0].q[0]).max()
    assert moved_by > 0.2, "the policy hardly moves the arm: the frames cannot differ"
    arm = ["meshcat", "arm"]
    try:
        with Browser() as browser:
            view = ViewerPage(browser, page)
            assert view.duration > 2.0
            browser.evaluate("viewer.animator.pause(); viewer.animator.reset(); true")
            t0, first, box0 = view.time, browser.screenshot(), view.screen_box(arm)
            started = time.monotonic()
            browser.evaluate("viewer.animator.play(); true")
            browser.wait_for("viewer.animator.time > 0.3", "the animation to reach 0.3 s")
            browser.evaluate("viewer.animator.pause(); true")
            waited, t1 = time.monotonic() - started, view.time
            second, box1 = browser.screenshot(), view.screen_box(arm)
            view.set_visible(arm, False)
            hidden = browser.screenshot()
    except BrowserError as err:
        pytest.fail(f"Chromium could not show the page: {err}")
    assert t0 == 0.0 and 0.3 < t1 <= waited + 0.1  # played, at most in real time
    assert box0 is not None and box1 is not None
    drawn = _changed(_pixels(second), _pixels(hidden))
    assert drawn.sum() > 2000, "the arm covers almost no pixels"
    assert _inside(drawn, [box1]) == drawn.sum(), "hiding the arm changed pixels elsewhere"
    moved = _changed(_pixels(first), _pixels(second))
    assert moved.sum() > 500, "the arm did not move on screen between the two frames"
    assert _inside(moved, [box0, box1]) > 0.9 * moved.sum(), \
        "the frames differ away from the arm"


def test_serve_shows_the_scene_live_and_ends_its_server(tiny_ur5_run):
    """--serve: the printed address serves MeshCat's viewer while the command runs, and a
    SIGTERM ends the command and its server (nothing left listening)."""
    import re
    import signal
    import subprocess
    import sys
    import urllib.error
    import urllib.request

    from cli_tools import child_env

    proc = subprocess.Popen([sys.executable, "-m", "analysis.replay", str(tiny_ur5_run),
                             "--episodes", "1", "--serve", "--no-progress"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=child_env())
    try:
        url = None
        for line in proc.stdout:
            found = re.search(r"serving at (\S+)", line)
            if found:
                url = found.group(1)
                break
        assert url is not None, proc.stderr.read()
        with urllib.request.urlopen(url, timeout=10) as page:
            assert page.status == 200 and b"MeshCat" in page.read()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0
        with pytest.raises(urllib.error.URLError):
            urllib.request.urlopen(url, timeout=5)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.parametrize("at", ["nan", "inf", "-1"])
def test_browser_refuses_a_time_that_is_not_finite_before_starting_one(tmp_path, capsys, at):
    """Issue 37, kind 7 (found by benchmarks/reliability_probe.py): ``--at nan`` passed the
    check (nan < 0 is false) and was found only after a browser had been waited for 30 s."""
    from benchmarks import browser

    page = tmp_path / "p.html"
    page.write_text("<html></html>")
    with pytest.raises(SystemExit) as stop:
        browser.main([str(page), "--at", at, "--out", str(tmp_path / "s.png")])
    assert stop.value.code == 2
    assert f"argument --at: {at} (expected a finite number >= 0 (s))" in capsys.readouterr().err


def test_serve_holds_sigterm_before_it_prints_the_address(monkeypatch):
    """A SIGTERM sent as soon as the address is read ends --serve cleanly: the handler is in
    place when the address is printed (under load the CI run's SIGTERM once came first, exit
    -15), and the default comes back after."""
    import builtins
    import signal

    from analysis import replay

    before, seen = signal.getsignal(signal.SIGTERM), []

    def announce(*args, **kwargs):
        seen.append(signal.getsignal(signal.SIGTERM))
        raise KeyboardInterrupt  # what the handler raises on SIGTERM

    monkeypatch.setattr(builtins, "print", announce)
    replay.serve_until_stopped("serving at http://127.0.0.1:7000/static/")
    assert len(seen) == 1 and callable(seen[0]) and seen[0] is not before
    assert signal.getsignal(signal.SIGTERM) is before


def test_a_page_replaces_only_a_page_without_force(tmp_path, capsys):
    """region_volumes --view (and replay --out: the same write_errors) replaced any file, a
    README included; now a file that is not a viewer page is refused naming it, nothing
    written; a page over a page (its ids differ run to run) and --force are written; a --view
    that is also a --plot output is refused before any work."""
    from analysis import region_volumes

    argv = ["--regions", "farbox", "--joints", "3", "--samples", "200"]
    other = tmp_path / "README.md"
    other.write_text("# someone's notes\n")
    with pytest.raises(SystemExit) as exc:
        region_volumes.main([*argv, "--view", str(other)])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "would replace" in err and str(other) in err, err
    assert other.read_text() == "# someone's notes\n"
    page = tmp_path / "regions.html"
    assert region_volumes.main([*argv, "--view", str(page)]) == 0
    first = page.read_bytes()
    assert region_volumes.main([*argv, "--view", str(page)]) == 0 and page.read_bytes() != first
    assert region_volumes.main([*argv, "--view", str(other), "--force"]) == 0
    assert b"MeshCat.Viewer" in other.read_bytes()
    assert "--force" in replay.build_parser().format_help()
    with pytest.raises(SystemExit) as exc:
        region_volumes.main([*argv, "--view", str(tmp_path / "v.json"), "--plot",
                             str(tmp_path / "v.png")])
    assert exc.value.code == 2 and "--view" in capsys.readouterr().err
    assert not list(tmp_path.glob("v.*"))
