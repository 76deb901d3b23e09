"""Recordings of a run: a picture, an animation or an OpenUSD file of a World's motion.

    with Recorder("pile.mp4", fps=30) as recorder:
        for step in range(300):
            world.step(1 / 60)
            if step % 2 == 0:
                recorder.capture(world)     # one copy of the transforms, nothing else

The format follows the extension: ``.png`` (the last frame captured), ``.gif``
and ``.mp4`` (every frame; MP4 through the ffmpeg that imageio-ffmpeg ships),
``.usd`` / ``.usda`` / ``.usdc`` (OpenUSD: each shape a mesh, each body a prim
with time-sampled transforms; needs ``usd-core``). A Recorder writes into a
temporary file beside ``path`` and renames it when closed, so a failed or
abandoned recording leaves no partial file; bad input (an unknown extension,
a directory that cannot be written, a bad camera) raises `RbgenError` naming
it before anything is simulated. ``background=True`` renders and encodes in
a separate process, so a simulation loop pays only for the copy of the
transforms and handing them over (rendering holds Python's GIL, so a thread
would not do).

A capture of a World does not drain its queue: it enqueues a non-blocking copy of the
transforms (`World.snapshot_frame`) and hands the previous capture's frame, whose copy
finished long ago, to the file; `close` adds the last one. So a frame reaches the file
one capture late (an error writing it shows at the next capture or at `close`), and the
frames written are exactly those that blocking reads at the same steps would give.
"""

from __future__ import annotations

import os
import queue as queue_module
import tempfile
import traceback
from pathlib import Path
from typing import Any

import numpy as np

from .errors import RbgenError
from .render.camera import coerce_camera
from .render.scene import Bodies, Frame, bodies_of, frame_of
from .snapshot import PendingFrame

#: extension -> format
FORMATS = {
    ".png": "png",
    ".gif": "gif",
    ".mp4": "mp4",
    ".usd": "usd",
    ".usda": "usd",
    ".usdc": "usd",
}
#: frames that may wait for a background renderer before `capture` waits for it
BACKGROUND_QUEUE = 32


def record_format(path) -> str:
    """The format of a recording path, from its extension (`RbgenError` if unknown)."""
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise RbgenError(
            f"record path {str(path)!r}: unknown extension {suffix or '(none)'!r}; "
            f"choose one of {sorted(FORMATS)}"
        )
    return FORMATS[suffix]


class Recorder:
    """Frames of a World (or of raw transforms) into one file at ``path``.

    ``camera``: a `rbgen.render.Camera`, a dict of its fields, or None (framed on
    the dynamic bodies of the first frame for animations, of the last for a PNG);
    ``width``, ``height``: image size; ``fps``: frames per second of an animation
    or of the USD time codes; ``samples``: multisampling (None: the renderer's
    default); ``background``: render and encode in a worker process. Use it as a
    context manager, or call `close` (or `abort`) yourself.
    """

    def __init__(
        self,
        path,
        camera=None,
        *,
        width: int = 640,
        height: int = 360,
        fps: float = 30.0,
        samples: int | None = None,
        background: bool = False,
    ):
        self.format = record_format(path)
        self.path = Path(path)
        self.camera = coerce_camera(camera)
        if not (
            isinstance(fps, (int, float, np.integer, np.floating)) and np.isfinite(fps) and fps > 0
        ):
            raise RbgenError(f"record fps must be a positive finite number, got {fps!r}")
        for name, value in (("width", width), ("height", height)):
            if not isinstance(value, (int, np.integer)) or not 16 <= value <= 8192:
                raise RbgenError(f"record {name} must be an integer in [16, 8192], got {value!r}")
        self.fps, self.width, self.height = float(fps), int(width), int(height)
        self.samples = samples
        self.frames = 0
        self._bodies: Bodies | None = None
        self._body_count = -1
        #: the last capture's snapshot and its bodies, added at the next capture or close
        self._pending: tuple[PendingFrame, Bodies] | None = None
        self._temp = _claim_temp(self.path)
        options: dict[str, Any]  # make_sink's keyword arguments
        options = {
            "format": self.format,
            "temp": str(self._temp),
            "camera": self.camera,
            "width": self.width,
            "height": self.height,
            "fps": self.fps,
            "samples": samples,
        }
        self._sink = _BackgroundSink(options) if background else make_sink(**options)
        self._closed = False

    # ------------------------------------------------------------- frames
    def capture(self, world, frame: Frame | PendingFrame | None = None) -> None:
        """Add the World's state now as a frame: a snapshot of its transforms
        (`World.snapshot_frame`: a non-blocking copy), or ``frame`` (a `Frame` already
        read, or a `PendingFrame` taken now, which several recorders may share). A pending
        frame is added to the file at the next capture, `add` or `close`, so the queue is
        never drained here. The bodies' shapes are read now, again only when their number
        changed, so a frame keeps the bodies it was taken with."""
        if self._closed:
            raise RbgenError(f"recording {str(self.path)!r} is closed")
        if frame is None:
            frame = world.snapshot_frame()
        if world.body_count != self._body_count:
            self._bodies = bodies_of(world)
            self._body_count = world.body_count
        assert self._bodies is not None  # read at the first capture (the count starts at -1)
        if isinstance(frame, PendingFrame):
            if frame.count != self._bodies.count:
                raise RbgenError(
                    f"the snapshot has {frame.count} bodies, the World {self._bodies.count} "
                    f"now: capture a snapshot when it is taken"
                )
            previous, self._pending = self._pending, (frame, self._bodies)
            self.frames += 1
            if previous is not None:
                self._write(previous[0].result(), previous[1])
            return
        self.add(frame, self._bodies)

    def add(self, frame: Frame, bodies: Bodies) -> None:
        """Add a frame of ``bodies`` (for transforms that do not come from a World)."""
        if self._closed:
            raise RbgenError(f"recording {str(self.path)!r} is closed")
        self._flush()
        self._write(frame, bodies)
        self.frames += 1

    def _flush(self) -> None:
        """Add the pending frame, if any (waits for its copy)."""
        if self._pending is not None:
            pending, bodies = self._pending
            self._pending = None
            self._write(pending.result(), bodies)

    def _write(self, frame: Frame, bodies: Bodies) -> None:
        if frame.positions.shape[0] != bodies.count:
            raise RbgenError(
                f"frame has {frame.positions.shape[0]} bodies, bodies has {bodies.count}"
            )
        try:
            self._sink.add(frame, bodies)
        except BaseException:
            self.abort()
            raise

    # ------------------------------------------------------------- ending
    def close(self) -> Path:
        """Finish the file and move it to ``path``; returns ``path``. A recording with no
        frame writes nothing and raises `RbgenError`."""
        if self._closed:
            return self.path
        try:
            self._flush()
        except BaseException:
            self.abort()
            raise
        if self.frames == 0:
            self.abort()
            raise RbgenError(f"recording {str(self.path)!r} has no frame; nothing written")
        try:
            self._sink.finish()
            os.chmod(self._temp, 0o666 & ~_umask())  # (mkstemp made it private)
            os.replace(self._temp, self.path)
        except BaseException:
            self.abort()
            raise
        self._closed = True
        return self.path

    def abort(self) -> None:
        """Drop the recording: no file at ``path`` is written or changed."""
        self._closed = True
        self._pending = None
        try:
            self._sink.cancel()
        finally:
            _remove(self._temp)

    def __enter__(self):
        return self

    def __exit__(self, kind, value, tb) -> None:
        if kind is None:
            self.close()
        else:
            self.abort()

    def __del__(self):
        if not getattr(self, "_closed", True):
            try:
                self.abort()
            except Exception:  # noqa: BLE001, S110 - interpreter shutdown; best effort
                pass


def record_hook(recorders, every: int = 1, blocking: bool = False):
    """``on_step(world, step)`` for `rbgen.harness.run_scene`: at step 0 and every ``every``
    steps, one snapshot of the transforms (`World.snapshot_frame`, no queue drain) feeds
    every recorder; each adds it to its file at its next capture or at `Recorder.close`.
    ``blocking``: one blocking read instead (`rbgen.render.scene.frame_of`: the queue
    drains, and each recorder adds the frame at once): the same frames, for a caller that
    wants them written as they are taken, and the baseline the snapshots are measured
    against."""
    if not isinstance(every, (int, np.integer)) or every < 1:
        raise RbgenError(f"record every must be a positive integer, got {every!r}")
    recorders = list(recorders)

    def on_step(world, step: int) -> None:
        if step % every == 0 and recorders:
            frame = frame_of(world) if blocking else world.snapshot_frame()
            for recorder in recorders:
                recorder.capture(world, frame)

    return on_step


# ----------------------------------------------------------------- files


def _claim_temp(path: Path) -> Path:
    """A fresh temporary file beside ``path`` with the same extension (encoders pick
    their format by it); `RbgenError` naming ``path`` when its directory cannot take it."""
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise RbgenError(f"record path {str(path)!r}: directory {str(directory)!r} does not exist")
    if path.is_dir():
        raise RbgenError(f"record path {str(path)!r} is a directory")
    try:
        fd, name = tempfile.mkstemp(
            prefix=f".{path.stem}.", suffix=f".partial{path.suffix}", dir=directory
        )
    except OSError as err:
        raise RbgenError(f"record path {str(path)!r} cannot be written: {err.strerror}") from None
    os.close(fd)
    return Path(name)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _remove(path: Path) -> None:
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass


# ----------------------------------------------------------------- sinks


def make_sink(format: str, temp: str, camera, width: int, height: int, fps: float, samples):
    """The writer of one format into ``temp``."""
    if format == "usd":
        from .render.usd import UsdSink

        return UsdSink(temp, fps)
    return _ImageSink(format, temp, camera, width, height, fps, samples)


class _ImageSink:
    """PNG (the last frame), GIF and MP4: frames rendered with `rbgen.render.Renderer`."""

    def __init__(self, format, temp, camera, width, height, fps, samples):
        self.format, self.temp, self.camera = format, temp, camera
        self.size, self.fps, self.samples = (width, height), fps, samples
        self._renderer = None
        self._last = None
        self._gif: list = []
        self._video = None

    def _render(self, frame, bodies, fix_camera: bool) -> np.ndarray:
        from .render.camera import Camera
        from .render.renderer import Renderer
        from .render.scene import scene_bounds

        if self._renderer is None:
            options = {} if self.samples is None else {"samples": self.samples}
            self._renderer = Renderer(*self.size, **options)
        camera = self.camera
        if camera is None and fix_camera:
            # an animation keeps the first frame's framing: a camera that follows the bodies
            # would hide their motion
            bounds = scene_bounds(bodies, frame, dynamic_only=True) or scene_bounds(bodies, frame)
            if bounds is not None:
                camera = self.camera = Camera.fit(*bounds, aspect=self.size[0] / self.size[1])
        return self._renderer.render(bodies, frame, camera)

    def add(self, frame, bodies):
        if self.format == "png":
            self._last = (frame, bodies)
            return
        image = self._render(frame, bodies, fix_camera=True)
        if self.format == "gif":
            from PIL import Image

            self._gif.append(
                Image.fromarray(image).quantize(
                    colors=255, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE
                )
            )
            return
        if self._video is None:
            import imageio_ffmpeg

            self._video = imageio_ffmpeg.write_frames(
                self.temp,
                self.size,
                fps=self.fps,
                codec="libx264",
                pix_fmt_out="yuv420p",
                quality=7,
                macro_block_size=2,
                ffmpeg_log_level="error",
            )
            self._video.send(None)
        self._video.send(np.ascontiguousarray(image))

    def finish(self):
        from PIL import Image

        if self.format == "png":
            image = self._render(*self._last, fix_camera=False)
            Image.fromarray(image).save(self.temp, format="PNG", optimize=True)
        elif self.format == "gif":
            first, rest = self._gif[0], self._gif[1:]
            first.save(
                self.temp,
                format="GIF",
                save_all=True,
                append_images=rest,
                loop=0,
                duration=max(20, round(1000 / self.fps)),
                optimize=False,
            )
        elif self._video is not None:
            self._video.close()
            self._video = None
        self.cancel()

    def cancel(self):
        if self._video is not None:
            self._video.close()
            self._video = None
        if self._renderer is not None:
            self._renderer.release()
            self._renderer = None


class _BackgroundSink:
    """A sink in a worker process (``python -m rbgen.record``, so that no user script is
    imported again, as multiprocessing's spawn would): `add` queues a frame for a feeder
    thread that pickles it into the worker's stdin (pipe writes release the GIL), waiting
    only when `BACKGROUND_QUEUE` frames are already queued; errors come back at `finish`."""

    def __init__(self, options: dict):
        import subprocess
        import sys
        import threading

        # the worker imports this rbgen, wherever it was imported from
        env = dict(os.environ)
        root = str(Path(__file__).resolve().parent.parent)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
        self._process = subprocess.Popen(
            [sys.executable, "-m", "rbgen.record"],
            env=env,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
        )
        self._queue: queue_module.Queue = queue_module.Queue(BACKGROUND_QUEUE)
        self._bodies_sent = None
        self._feed_error: BaseException | None = None
        self._queue.put(options)
        self._feeder = threading.Thread(target=self._feed, daemon=True)
        self._feeder.start()

    def _feed(self):
        import pickle

        try:
            while True:
                item = self._queue.get()
                pickle.dump(item, self._process.stdin, protocol=pickle.HIGHEST_PROTOCOL)
                if isinstance(item, str):
                    self._process.stdin.close()
                    return
        except BaseException as err:  # noqa: BLE001 - reported by add / finish
            self._feed_error = err

    def add(self, frame, bodies):
        if self._feed_error is not None or self._process.poll() is not None:
            raise RbgenError(f"the background recorder stopped: {self._outcome()}")
        send_bodies = bodies if bodies is not self._bodies_sent else None
        self._bodies_sent = bodies
        self._queue.put((frame.positions, frame.orientations, send_bodies))

    def _outcome(self) -> str:
        self._feeder.join(timeout=5)
        assert self._process.stdout is not None  # a pipe (Popen with stdout=PIPE)
        out = self._process.stdout.read().decode(errors="replace").strip()
        self._process.wait()
        return out or (
            repr(self._feed_error)
            if self._feed_error
            else f"worker exit code {self._process.returncode}"
        )

    def finish(self):
        self._queue.put("finish")
        outcome = self._outcome()
        if outcome != "ok":
            raise RbgenError(f"the background recorder failed: {outcome}")

    def cancel(self):
        if self._process.poll() is None:
            self._process.kill()
        self._process.wait()


def _worker(stdin, stdout) -> int:
    """The background recorder: options, then frames, then "finish", pickled on ``stdin``;
    writes "ok" or the error to ``stdout``."""
    import pickle

    try:
        sink = make_sink(**pickle.load(stdin))
        bodies = None
        while True:
            item = pickle.load(stdin)
            if isinstance(item, str) and item == "finish":
                break
            positions, orientations, new_bodies = item
            bodies = new_bodies if new_bodies is not None else bodies
            sink.add(Frame(positions, orientations), bodies)
        sink.finish()
        stdout.write(b"ok")
        return 0
    except BaseException as err:  # noqa: BLE001 - reported to the parent
        stdout.write(f"{type(err).__name__}: {err}\n{traceback.format_exc(limit=3)}".encode())
        return 1


if __name__ == "__main__":
    import sys

    sys.exit(_worker(sys.stdin.buffer, sys.stdout.buffer))
