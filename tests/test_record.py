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
