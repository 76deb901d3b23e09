"""rbgen.record: animations have the frames asked for, USD files re-open with their prims and
time samples, and bad input fails before anything is written, leaving no file behind."""

from __future__ import annotations

import os
import warnings

import numpy as np
import pytest

from rbgen.errors import RbgenError
from rbgen.record import Recorder, record_hook
from rbgen.render import Bodies, Frame
from rbgen.shapes import Box, Capsule, ConvexHull, Plane, Sphere

SIZE = {"width": 64, "height": 48}


def falling(frames: int):
    """Synthetic bodies of every kind and ``frames`` frames of them falling and turning."""
    shapes = [
        Plane((0, 1, 0), 0.0),
        Box((0.5, 0.5, 0.5)),
        Sphere(0.4),
        Capsule(0.2, 0.4),
        ConvexHull(np.random.default_rng(1).normal(size=(16, 3)) * 0.4),
    ]
    bodies = Bodies.make(shapes, [0, 1, 2, 3, 4, 1], static=[True] + [False] * 5)
    out = []
    for t in range(frames):
        positions = np.array([[0, 0, 0]] + [[1.2 * k, 3.0 - 0.1 * t, 0.0] for k in range(5)])
        angle = 0.1 * t
        q = np.tile([0.0, np.sin(angle / 2), 0.0, np.cos(angle / 2)], (6, 1))
        q[0] = (0, 0, 0, 1)
        out.append(Frame.make(positions, q, 6))
    return bodies, out


def leftovers(directory) -> list[str]:
    return sorted(name for name in os.listdir(directory) if ".partial" in name)


@pytest.mark.parametrize("extension", [".gif", ".mp4"])
def test_animation_has_the_requested_number_of_frames(tmp_path, extension, headless_gl):
    bodies, frames = falling(7)
    path = tmp_path / f"fall{extension}"
    with Recorder(path, fps=10, **SIZE) as recorder:
        for frame in frames:
            recorder.add(frame, bodies)
    assert recorder.frames == 7
    if extension == ".gif":
        from PIL import Image

        with Image.open(path) as image:
            assert image.n_frames == 7 and image.size == (64, 48)
    else:
        import imageio_ffmpeg

        reader = imageio_ffmpeg.read_frames(str(path))
        meta = next(reader)
        assert tuple(meta["size"]) == (64, 48)
        assert sum(1 for _ in reader) == 7
    assert leftovers(tmp_path) == []


def test_png_is_the_last_frame(tmp_path, headless_gl):
    from PIL import Image

    bodies, frames = falling(3)
    with Recorder(tmp_path / "last.png", **SIZE) as recorder:
        for frame in frames:
            recorder.add(frame, bodies)
    with Image.open(tmp_path / "last.png") as image:
        assert image.size == (64, 48) and image.format == "PNG"


def test_usd_reopens_with_prims_time_samples_and_transforms(tmp_path):
    """Every body is a prim under /World/Bodies with one time sample per frame of its
    translate and orient ops, equal to the frames given; static bodies have none."""
    pytest.importorskip("pxr", reason="writing .usd needs usd-core (pip install 'rbgen[usd]')")
    from pxr import Gf, Usd, UsdGeom

    bodies, frames = falling(5)
    path = tmp_path / "fall.usda"
    with Recorder(path, fps=25) as recorder:
        for frame in frames:
            recorder.add(frame, bodies)
    stage = Usd.Stage.Open(str(path))
    assert stage.GetTimeCodesPerSecond() == 25
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, 4)
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    bodies_prim = stage.GetPrimAtPath("/World/Bodies")
    assert len(bodies_prim.GetChildren()) == 6
    kinds = sorted(
        p.GetName().split("_")[0] for p in stage.GetPrimAtPath("/World/Shapes").GetChildren()
    )
    assert kinds == ["box", "capsule", "hull", "plane", "sphere"]
    for i in range(6):
        prim = stage.GetPrimAtPath(f"/World/Bodies/body_{i:06d}")
        assert prim.IsValid()
        mesh = prim.GetChild("geometry")
        assert mesh.IsA(UsdGeom.Mesh) and len(mesh.GetAttribute("points").Get()) > 0
        translate = prim.GetAttribute("xformOp:translate")
        if i == 0:  # the static plane
            assert translate.GetNumTimeSamples() == 0
            continue
        assert translate.GetTimeSamples() == [0, 1, 2, 3, 4]
        xform = UsdGeom.Xformable(prim)
        for t, frame in enumerate(frames):
            assert np.allclose(translate.Get(t), frame.positions[i], atol=1e-6)
            q = prim.GetAttribute("xformOp:orient").Get(t)
            x, y, z, w = frame.orientations[i]
            assert np.allclose([q.GetReal(), *q.GetImaginary()], [w, x, y, z], atol=1e-6)
            # the composed transform moves the body's origin to its position
            m = xform.ComputeLocalToWorldTransform(t)
            assert np.allclose(m.Transform(Gf.Vec3d(0, 0, 0)), frame.positions[i], atol=1e-5)


def test_world_recording_reads_transforms_once_per_frame(tmp_path, headless_gl):
    """A World run through `record_hook` every 2 steps: 1 + steps / 2 frames in each file,
    the USD's last sample equal to the World's positions at the end."""
    pytest.importorskip("pxr", reason="writing .usd needs usd-core (pip install 'rbgen[usd]')")
    from pxr import Usd

    import rbgen

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        world = rbgen.World()
    world.add_static(rbgen.Plane((0, 1, 0), 0.0))
    ids = world.add_bodies(rbgen.Box((0.5, 0.5, 0.5)), positions=[[0, 0.6, 0], [0, 1.8, 0]])
    world.add_bodies(rbgen.Sphere(0.3), positions=[[2, 1, 0]])
    recorders = [Recorder(tmp_path / "w.usd"), Recorder(tmp_path / "w.gif", **SIZE)]
    hook = record_hook(recorders, every=2)
    hook(world, 0)
    for step in range(1, 7):
        world.step(1 / 60)
        hook(world, step)
    for recorder in recorders:
        recorder.close()
        assert recorder.frames == 4
    stage = Usd.Stage.Open(str(tmp_path / "w.usd"))
    translate = stage.GetPrimAtPath(f"/World/Bodies/body_{ids[1]:06d}").GetAttribute(
        "xformOp:translate"
    )
    assert translate.GetNumTimeSamples() == 4
    assert np.allclose(translate.Get(3), world.positions[ids[1]], atol=1e-6)


def test_background_recording_writes_the_same_frames(tmp_path, headless_gl):
    from PIL import Image

    bodies, frames = falling(4)
    with Recorder(tmp_path / "bg.gif", background=True, **SIZE) as recorder:
        for frame in frames:
            recorder.add(frame, bodies)
    with Image.open(tmp_path / "bg.gif") as image:
        assert image.n_frames == 4
    assert leftovers(tmp_path) == []


def test_unknown_extension_is_refused_naming_it(tmp_path):
    with pytest.raises(RbgenError, match=r"\.avi"):
        Recorder(tmp_path / "run.avi")
    with pytest.raises(RbgenError, match="extension"):
        Recorder(tmp_path / "run")
    assert os.listdir(tmp_path) == []


def test_unwritable_path_is_refused_naming_it(tmp_path):
    missing = tmp_path / "no" / "such" / "dir" / "run.mp4"
    with pytest.raises(RbgenError, match="no/such/dir"):
        Recorder(missing)
    a_file = tmp_path / "file.txt"
    a_file.write_text("x")
    with pytest.raises(RbgenError, match="file.txt"):
        Recorder(a_file / "run.png")
    (tmp_path / "dir.png").mkdir()
    with pytest.raises(RbgenError, match="is a directory"):
        Recorder(tmp_path / "dir.png")


@pytest.mark.parametrize(
    "camera, named",
    [
        ({"eye": (float("nan"), 0, 0)}, "eye"),
        ({"eye": (1, 1, 1), "target": (1, 1, 1)}, "view direction is zero"),
        ({"colour": 1}, "unknown field"),
    ],
)
def test_bad_camera_is_refused_before_anything_is_written(tmp_path, camera, named):
    with pytest.raises(RbgenError, match=named):
        Recorder(tmp_path / "run.png", camera=camera)
    assert os.listdir(tmp_path) == []


def test_failed_recording_leaves_no_file(tmp_path, headless_gl):
    """An error inside the recording's block drops it: no file, no temporary left; an
    existing file at the path is left as it was."""
    bodies, frames = falling(2)
    path = tmp_path / "run.gif"
    path.write_bytes(b"before")
    with pytest.raises(KeyboardInterrupt), Recorder(path, **SIZE) as recorder:
        recorder.add(frames[0], bodies)
        raise KeyboardInterrupt  # (a run stopped by hand)
    assert path.read_bytes() == b"before" and leftovers(tmp_path) == []
    with pytest.raises(RbgenError, match="no frame"):
        Recorder(tmp_path / "empty.mp4").close()
    assert not (tmp_path / "empty.mp4").exists() and leftovers(tmp_path) == []


def test_frame_of_the_wrong_size_is_refused(tmp_path, headless_gl):
    bodies, _ = falling(1)
    recorder = Recorder(tmp_path / "x.usda")
    with pytest.raises(RbgenError, match="positions must have shape"):
        recorder.add(Frame.make(np.zeros((2, 3)), np.zeros((6, 4)), 6), bodies)
    recorder.abort()
    assert os.listdir(tmp_path) == []


def test_rbgen_run_records_every_k_steps(tmp_path, capsys, headless_gl):
    """`rbgen run --record` (twice): frames at step 0 and every K steps, paths printed."""
    from PIL import Image

    pytest.importorskip("pxr", reason="writing .usd needs usd-core (pip install 'rbgen[usd]')")
    from pxr import Usd

    from rbgen.cli import main

    gif, usd = tmp_path / "p.gif", tmp_path / "p.usda"
    assert (
        main(
            [
                "run",
                "pyramid",
                "--n",
                "3",
                "--steps",
                "6",
                "--record",
                str(gif),
                "--record",
                str(usd),
                "--record-every",
                "2",
                "--record-size",
                "64x48",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert f"wrote {gif.resolve()} (4 frames)" in out and str(usd.resolve()) in out
    with Image.open(gif) as image:
        # Pillow merges identical consecutive frames into one of their summed duration,
        # so the GIF lasts 4 frames whether or not the pyramid moved between them
        durations = []
        for index in range(image.n_frames):
            image.seek(index)
            durations.append(image.info["duration"])
        # `rbgen run` records at 30 fps: 33 ms a frame, which GIF stores in hundredths
        assert sum(durations) == 4 * 30
    assert Usd.Stage.Open(str(usd)).GetEndTimeCode() == 3


def test_rbgen_demo_writes_its_animation_and_says_where(tmp_path, capsys, monkeypatch, headless_gl):
    monkeypatch.chdir(tmp_path)
    from rbgen.cli import main

    assert main(["demo", "--n", "10", "--steps", "10", "--record-size", "64x48"]) == 0
    out = capsys.readouterr().out
    assert f"wrote {(tmp_path / 'rbgen-demo.mp4').resolve()} (3 frames)" in out


def test_rbgen_run_refuses_a_bad_record_path_before_simulating(tmp_path, capsys):
    from rbgen.cli import main

    assert (
        main(["run", "pyramid", "--n", "3", "--steps", "6", "--record", str(tmp_path / "p.webm")])
        == 2
    )
    err = capsys.readouterr()
    assert ".webm" in err.err and "pyramid" not in err.out
    assert os.listdir(tmp_path) == []


# ----------------------------------------------------------------- pending captures (issue 28)


class ListSink:
    """A sink that keeps what it is given (frames and their bodies), for comparisons."""

    def __init__(self, kept: list):
        self.kept = kept

    def add(self, frame, bodies):
        self.kept.append((frame, bodies))

    def finish(self):
        pass

    def cancel(self):
        pass


@pytest.fixture
def kept(monkeypatch):
    """The frames every Recorder made in the test gives its sink, one list per Recorder."""
    import rbgen.record

    sinks: list[list] = []

    def make_sink(**options):
        sinks.append([])
        return ListSink(sinks[-1])

    monkeypatch.setattr(rbgen.record, "make_sink", make_sink)
    return sinks


def pile_world(runtime, **options):
    import rbgen

    world = rbgen.World(runtime, **options)
    world.add_static(rbgen.Plane((0, 1, 0), 0.0))
    world.add_bodies(
        rbgen.Box((0.5, 0.5, 0.5)),
        positions=[[0.15 * i, 0.5 + 1.05 * i, 0.05 * i] for i in range(6)],
    )
    world.add_bodies(rbgen.Sphere(0.3), positions=[[2, 1, 0], [2, 2, 0.1]])
    return world


def blocking_hook(recorders, every):
    """`record_hook` as it was before snapshots: a blocking read at each capture."""
    return record_hook(recorders, every, blocking=True)


def run_recorded(world, hook, steps=13):
    hook(world, 0)
    for step in range(1, steps + 1):
        world.step(1 / 60)
        hook(world, step)


@pytest.mark.parametrize("options", [{}, {"pair_capacity": 1, "manifold_capacity": 1}])
def test_pending_recording_equals_the_blocking_one(runtime, kept, options, tmp_path):
    """The same deterministic run (with redone steps too: one-pair buffers) recorded by
    `record_hook` (snapshots, one frame late) and by blocking reads: the same frames,
    bit for bit, with the same bodies, and no frame is in the sink before the next
    capture."""
    recordings = []
    for make_hook in (record_hook, blocking_hook):
        world = pile_world(runtime, **options)
        recorder = Recorder(tmp_path / "r.usda")
        run_recorded(world, make_hook([recorder], 3))
        recorder.close()
        assert recorder.frames == 5
        recordings.append(kept[-1])
        if options:
            assert world.overflows >= 1
    pending, blocking = recordings
    assert len(pending) == len(blocking) == 5
    for (a, bodies_a), (b, bodies_b) in zip(pending, blocking):
        np.testing.assert_array_equal(a.positions, b.positions)
        np.testing.assert_array_equal(a.orientations, b.orientations)
        np.testing.assert_array_equal(bodies_a.shape_index, bodies_b.shape_index)
        np.testing.assert_array_equal(bodies_a.static, bodies_b.static)
    assert not np.array_equal(pending[0][0].positions, pending[-1][0].positions)


def test_pending_usd_file_equals_the_blocking_one(runtime, tmp_path):
    """End to end: the USD files of a run recorded with snapshots and with blocking reads
    are the same bytes."""
    pytest.importorskip("pxr", reason="writing .usd needs usd-core (pip install 'rbgen[usd]')")
    paths = []
    for make_hook, name in ((record_hook, "pending.usda"), (blocking_hook, "blocking.usda")):
        world = pile_world(runtime)
        with Recorder(tmp_path / name) as recorder:
            run_recorded(world, make_hook([recorder], 2), steps=8)
        paths.append(tmp_path / name)
    assert paths[0].read_bytes() == paths[1].read_bytes()


def test_close_writes_the_pending_frame(runtime, tmp_path):
    """The last capture is still pending at close: close adds it (the USD's last sample is
    the World's state at the last capture, not at close)."""
    pytest.importorskip("pxr", reason="writing .usd needs usd-core (pip install 'rbgen[usd]')")
    from pxr import Usd

    world = pile_world(runtime)
    recorder = Recorder(tmp_path / "last.usd")
    for _ in range(3):
        world.step(1 / 60)
        recorder.capture(world)
    at_capture = world.positions.copy()
    assert recorder._pending is not None and recorder.frames == 3
    for _ in range(5):
        world.step(1 / 60)
    recorder.close()
    stage = Usd.Stage.Open(str(tmp_path / "last.usd"))
    translate = stage.GetPrimAtPath("/World/Bodies/body_000003").GetAttribute("xformOp:translate")
    assert translate.GetTimeSamples() == [0, 1, 2]
    assert np.array_equal(np.array(translate.Get(2), np.float32), at_capture[3])
    assert not np.array_equal(at_capture[3], world.positions[3])


def test_bodies_removed_between_captures_keep_each_frame_with_its_bodies(runtime, kept, tmp_path):
    """Bodies removed (and added) while a capture is pending: the pending frame goes to the
    file with the bodies it was taken with, the next with the new ones, and the values
    are the blocking reads' at each capture. A snapshot captured after the count changed
    is refused, naming both counts."""
    from rbgen.render.scene import frame_of

    world = pile_world(runtime)
    recorder = Recorder(tmp_path / "r.usda")
    expected = []
    for removal in ([1, 2], [0], None):
        for _ in range(3):
            world.step(1 / 60)
        recorder.capture(world)
        expected.append(frame_of(world))
        if removal is not None:
            world.remove_bodies(removal)
    world.add_bodies(rbgen_sphere(), positions=[[5, 1, 0]])
    stale = world.snapshot_frame()
    world.remove_bodies([0])
    with pytest.raises(RbgenError, match="snapshot has 7 bodies, the World 6"):
        recorder.capture(world, stale)
    recorder.close()
    frames = kept[-1]
    assert [bodies.count for _, bodies in frames] == [9, 7, 6]
    for (frame, bodies), blocking in zip(frames, expected):
        assert frame.positions.shape[0] == bodies.count
        np.testing.assert_array_equal(frame.positions, blocking.positions)
        np.testing.assert_array_equal(frame.orientations, blocking.orientations)


def rbgen_sphere():
    import rbgen

    return rbgen.Sphere(0.25)


@pytest.mark.parametrize("steps", [0, 2])
def test_empty_world_records_as_the_blocking_path_does(runtime, tmp_path, steps):
    """A World with no body: the pending path ends as the blocking one does (the same
    file, or the same error)."""
    pytest.importorskip("pxr", reason="writing .usd needs usd-core (pip install 'rbgen[usd]')")
    import rbgen

    outcomes = []
    for make_hook, name in ((record_hook, "pending.usda"), (blocking_hook, "blocking.usda")):
        world = rbgen.World(runtime)
        try:
            with Recorder(tmp_path / name) as recorder:
                run_recorded(world, make_hook([recorder], 1), steps=steps)
            outcomes.append(("file", (tmp_path / name).read_bytes()))
        except Exception as err:  # noqa: BLE001 - compared below
            outcomes.append((type(err).__name__, str(err)))
    assert outcomes[0] == outcomes[1]
