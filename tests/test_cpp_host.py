"""The C++ host (rbgen/host, examples/cpp): built with CMake, it replays an exported World's
steps on the same device bit for bit, grows and redoes as Python does, and refuses
exports it cannot run.

The example is built once per session (``cmake``, a C++17 compiler and the OpenCL headers
and ICD loader are needed: ``.ci/run`` installs them on Debian).
"""

from __future__ import annotations

import atexit
import functools
import json
import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pyopencl
import pytest

import rbgen
from rbgen.export import export_world
from rbgen.harness import build_scene

ROOT = Path(__file__).resolve().parent.parent
STEPS = 100


@pytest.fixture(scope="session")
def rbgen_run(tmp_path_factory) -> Path:
    """The rbgen_run example, configured and built with CMake."""
    if shutil.which("cmake") is None:
        pytest.skip("cmake is not installed (.ci/run installs it)")
    build = tmp_path_factory.mktemp("cpp_build")
    for command in (
        [
            "cmake",
            "-S",
            str(ROOT / "examples" / "cpp"),
            "-B",
            str(build),
            "-DCMAKE_BUILD_TYPE=Release",
        ],
        ["cmake", "--build", str(build), "-j", "2"],
    ):
        done = subprocess.run(command, capture_output=True, text=True)
        assert done.returncode == 0, done.stdout + done.stderr
    return build / "rbgen_run"


def export(runtime, scene: str, n: int, out: Path, **options) -> Path:
    """Export a harness scene's World (its kernels, plan and schedule) on ``runtime``."""
    world = build_scene(scene, n, runtime, **options)[0]
    world.step(1 / 60)
    world.statistics()
    export_world(world, out, build=lambda: build_scene(scene, n, runtime, **options)[0])
    return out


@functools.cache
def host_environment() -> dict:
    """The environment the C++ host runs in (made once a session): its ICD loader (the
    system's) must see the device pyopencl exported for. pyopencl's wheels bundle PoCL with
    an ICD file of their own, which the system's loader does not read; on a machine with no
    ICD files of its own (no /etc/OpenCL/vendors), OCL_ICD_VENDORS names a folder holding
    that file, its library by absolute path (the folder is removed when the session ends).
    Elsewhere (the system's PoCL installed, or OCL_ICD_VENDORS set) the environment is left
    as it is: two PoCLs in one process are best avoided."""
    env = dict(os.environ)
    system = Path("/etc/OpenCL/vendors")
    if "OCL_ICD_VENDORS" in env or any(system.glob("*.icd")):
        return env
    libs = Path(pyopencl.__file__).resolve().parent / ".libs"
    bundled = sorted(libs.glob("*.icd"))
    if bundled:
        folder = Path(tempfile.mkdtemp(prefix="rbgen-icd-"))
        atexit.register(shutil.rmtree, folder, True)
        for icd in bundled:
            library = Path(icd.read_text().strip())
            library = library if library.is_absolute() else libs / library
            (folder / icd.name).write_text(f"{library}\n")
        env["OCL_ICD_VENDORS"] = str(folder)
    return env


def run(binary: Path, directory: Path, steps: int, *options: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(binary), str(directory), str(steps), *options],
        capture_output=True,
        text=True,
        timeout=600,
        env=host_environment(),
    )


def python_state(runtime, scene: str, n: int, steps: int, **options) -> list[np.ndarray]:
    world = build_scene(scene, n, runtime, **options)[0]
    for _ in range(steps):
        world.step(1 / 60)
    return [world.positions, world.orientations, world.linear_velocities, world.angular_velocities]


def dumped_state(path: Path, n: int) -> list[np.ndarray]:
    """rbgen_run --dump: positions, orientations, linear and angular velocities."""
    raw = np.fromfile(path, np.float32)
    assert raw.size == n * 13
    p, q, v, w = np.split(raw, np.cumsum([3 * n, 4 * n, 3 * n]))
    return [p.reshape(n, 3), q.reshape(n, 4), v.reshape(n, 3), w.reshape(n, 3)]


def overflows(stdout: str) -> int:
    return int(re.search(r"overflows (\d+)", stdout).group(1))


@pytest.fixture(scope="module")
def boxbox(runtime, tmp_path_factory) -> Path:
    return export(runtime, "boxbox", 1000, tmp_path_factory.mktemp("boxbox1000"))


@pytest.fixture(scope="module")
def boxbox_python(runtime) -> list[np.ndarray]:
    return python_state(runtime, "boxbox", 1000, STEPS)


def assert_same(cpp: list[np.ndarray], python: list[np.ndarray]) -> None:
    for name, a, b in zip(
        ("positions", "orientations", "linear velocities", "angular velocities"), cpp, python
    ):
        assert a.shape == b.shape
        assert a.tobytes() == b.tobytes(), (
            f"{name} differ (largest difference {np.abs(a - b).max():.3g})"
        )


def test_cpp_host_runs_boxbox_bit_for_bit(rbgen_run, boxbox, boxbox_python, tmp_path):
    """BoxBox 1,000 for 100 steps in C++: positions, orientations and velocities equal the
    Python World's after the same steps, bit for bit (same device, kernels and order), and
    the sanity line sees no NaN."""
    done = run(rbgen_run, boxbox, STEPS, "--dump", str(tmp_path / "state.bin"), "--json")
    assert done.returncode == 0, done.stdout + done.stderr
    result = json.loads(done.stdout.split("result ", 1)[1])
    assert result["steps"] == STEPS and result["nans"] == 0 and result["overflows"] == 0
    assert result["bodies"] == 1001 and result["ms_per_step"] > 0
    assert_same(dumped_state(tmp_path / "state.bin", 1001), boxbox_python)


def test_cpp_host_grows_from_the_smallest_capacities_and_still_matches(
    rbgen_run, boxbox, boxbox_python, tmp_path
):
    """Started with one pair and one manifold, the C++ host overflows, grows to powers of
    two and redoes the steps (restoring the bodies from the backup, rewinding the
    constraint ring), and still ends bit for bit where Python does."""
    done = run(
        rbgen_run,
        boxbox,
        STEPS,
        "--capacity",
        "pairs=0",
        "--capacity",
        "manifolds=0",
        "--dump",
        str(tmp_path / "state.bin"),
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert overflows(done.stdout) >= 1
    assert "manifolds=4096" in done.stdout or "manifolds=8192" in done.stdout
    assert_same(dumped_state(tmp_path / "state.bin", 1001), boxbox_python)


def test_cpp_host_grows_mid_run_keeping_the_warm_start(runtime, rbgen_run, tmp_path):
    """A pile landing: contacts appear after some steps, so the manifold capacity overflows
    mid-run, when the previous step's constraints are the warm start of the redo; each ring
    generation grows when it is next written (a follower), and the C++ host matches."""
    out = export(runtime, "box_pile", 100, tmp_path / "pile")
    done = run(
        rbgen_run, out, 90, "--capacity", "manifolds=4", "--dump", str(tmp_path / "state.bin")
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert overflows(done.stdout) >= 1
    assert_same(
        dumped_state(tmp_path / "state.bin", 101), python_state(runtime, "box_pile", 100, 90)
    )


def test_cpp_host_replays_sleeping_islands_with_redos(runtime, rbgen_run, tmp_path):
    """A landing pile with sleeping on, from a manifold buffer of 4: islands fall asleep
    and wake in the exported steps, overflowing steps are redone from the sleep records'
    backup (the undo), and the C++ host matches Python bit for bit."""
    out = export(runtime, "box_pile", 100, tmp_path / "pile", sleeping=True)
    done = run(
        rbgen_run, out, 250, "--capacity", "manifolds=4", "--dump", str(tmp_path / "state.bin")
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert overflows(done.stdout) >= 1
    python = python_state(runtime, "box_pile", 100, 250, sleeping=True)
    assert not python[2][1:].any() and not python[3][1:].any()  # (the pile sleeps by then)
    assert_same(dumped_state(tmp_path / "state.bin", 101), python)


def mesh_and_compounds(runtime):
    """A wavy 12 x 12 triangle mesh, 18 boxes and two compounds (a box and a sphere)."""
    world = rbgen.World(runtime)
    k = 12
    x, z = np.meshgrid(np.arange(k + 1) - k / 2, np.arange(k + 1) - k / 2, indexing="ij")
    vertices = np.stack([x.ravel(), 0.1 * np.sin(x.ravel()) * np.cos(z.ravel()), z.ravel()], 1)
    quads = [(i * (k + 1) + j, (i + 1) * (k + 1) + j) for i in range(k) for j in range(k)]
    triangles = [t for a, c in quads for t in ((a, c, a + 1), (a + 1, c, c + 1))]
    world.add_static(rbgen.TriangleMesh(vertices, np.array(triangles)))
    boxes = [[i * 1.2 - 3, 1.0 + j * 1.1, 0.3 * j] for i in range(6) for j in range(3)]
    world.add_bodies(rbgen.Box((0.4, 0.4, 0.4)), mass=1.0, positions=boxes)
    compound = rbgen.Compound(
        [
            (rbgen.Box((0.3, 0.1, 0.3)), (0, 0, 0), (0, 0, 0, 1)),
            (rbgen.Sphere(0.2), (0, 0.3, 0), (0, 0, 0, 1)),
        ]
    )
    world.add_bodies(compound, mass=1.0, positions=[[0, 5, 0], [1.5, 5, 0]])
    return world


def test_cpp_host_runs_meshes_and_compounds_growing_every_expansion(runtime, rbgen_run, tmp_path):
    """A World with a triangle mesh and compounds: the midphase's two expansions are
    capacities of their own (their need in the step report); started at one pair each,
    with one pair and one manifold, the C++ host grows all of them and still ends bit for
    bit where Python does."""
    world = mesh_and_compounds(runtime)
    world.step(1 / 60)
    world.statistics()
    out = tmp_path / "mesh"
    export_world(world, out, build=lambda: mesh_and_compounds(runtime))
    schedule = json.loads((out / "schedule.json").read_text())
    names = [c["name"] for c in schedule["capacities"]]
    assert {"midphase.children", "midphase.triangles", "pairs", "manifolds"} == set(names)
    options = [item for name in names for item in ("--capacity", f"{name}=0")]
    done = run(rbgen_run, out, 60, *options, "--dump", str(tmp_path / "state.bin"))
    assert done.returncode == 0, done.stdout + done.stderr
    assert overflows(done.stdout) >= len(names)
    python = mesh_and_compounds(runtime)
    for _ in range(60):
        python.step(1 / 60)
    assert_same(
        dumped_state(tmp_path / "state.bin", python.body_count),
        [
            python.positions,
            python.orientations,
            python.linear_velocities,
            python.angular_velocities,
        ],
    )


def _edited(source: Path, target: Path, edit) -> Path:
    shutil.copytree(source, target)
    edit(target)
    return target


def _schedule_edit(change):
    def edit(directory: Path) -> None:
        path = directory / "schedule.json"
        schedule = json.loads(path.read_text())
        change(schedule)
        path.write_text(json.dumps(schedule))

    return edit


def test_cpp_host_refuses_another_device_naming_both_fingerprints(rbgen_run, boxbox, tmp_path):
    """An export made for another device or driver: both fingerprints are named, and the
    command that exports it again here."""

    def other(schedule):
        schedule["device"].update(
            fingerprint="nvidia-h200-0123456789ab",
            device_name="NVIDIA H200",
            driver_version="570.00",
        )

    directory = _edited(boxbox, tmp_path / "other", _schedule_edit(other))
    done = run(rbgen_run, directory, 1)
    assert done.returncode == 1
    expected = json.loads((boxbox / "schedule.json").read_text())["device"]["fingerprint"]
    assert "nvidia-h200-0123456789ab" in done.stderr and expected in done.stderr
    assert "rbgen export --world" in done.stderr or "export_world" in done.stderr


def test_cpp_host_refuses_missing_and_corrupted_files_naming_them(rbgen_run, boxbox, tmp_path):
    """A missing kernel file, a changed data file, a truncated schedule: each refused with
    the file's name."""
    schedule = json.loads((boxbox / "schedule.json").read_text())
    program = schedule["programs"][0]["file"]
    data = next(name for name in schedule["files"] if name.startswith("data/"))

    missing = _edited(boxbox, tmp_path / "missing", lambda d: (d / program).unlink())
    done = run(rbgen_run, missing, 1)
    assert done.returncode == 1 and program in done.stderr and "cannot open" in done.stderr

    def flip(directory: Path) -> None:
        raw = bytearray((directory / data).read_bytes())
        raw[len(raw) // 2] ^= 1
        (directory / data).write_bytes(bytes(raw))

    corrupted = _edited(boxbox, tmp_path / "corrupted", flip)
    done = run(rbgen_run, corrupted, 1)
    assert done.returncode == 1 and data in done.stderr and "corrupted" in done.stderr

    def truncate(directory: Path) -> None:
        text = (directory / "schedule.json").read_text()
        (directory / "schedule.json").write_text(text[: len(text) // 2])

    truncated = _edited(boxbox, tmp_path / "truncated", truncate)
    done = run(rbgen_run, truncated, 1)
    assert done.returncode == 1 and "schedule.json" in done.stderr and "JSON" in done.stderr


def test_cpp_host_refuses_an_unknown_format_version(rbgen_run, boxbox, tmp_path):
    """A schedule of another format version: refused, naming both versions."""
    directory = _edited(boxbox, tmp_path / "v2", _schedule_edit(lambda s: s.update(version=2)))
    done = run(rbgen_run, directory, 1)
    assert done.returncode == 1
    assert "version 2" in done.stderr and "version 1" in done.stderr


def jointed_scene(runtime):
    """A 12-link box chain hung from the world by a hinge and on ball joints (one with a
    break impulse it exceeds on landing), falling onto three boxes on the ground."""
    world = rbgen.World(runtime, substeps=2)
    world.add_static(rbgen.Box((6, 0.5, 6)), position=(0, -0.5, 0))
    world.add_bodies(
        rbgen.Box((0.2, 0.2, 0.2)), positions=[[x, 0.2, 0.0] for x in (-0.4, 0.0, 0.4)]
    )
    n = 12
    centres = np.array([[-0.6 + (i + 0.5) * 0.1, 0.5, 0.02 * i] for i in range(n)])
    links = world.add_bodies(rbgen.Box((0.045, 0.02, 0.02)), mass=0.5, positions=centres)
    world.add_joint(rbgen.HingeJoint(int(links[0]), None, anchor=(-0.6, 0.5, 0), axis=(0, 0, 1)))
    world.add_joints(
        rbgen.BallJoint,
        a=links[1:],
        b=links[:-1],
        anchor=centres[1:] - (0.05, 0, 0),
        break_impulse=[None] * 9 + [0.2, None],
    )
    return world


def test_cpp_host_replays_a_jointed_world_bit_for_bit(runtime, rbgen_run, tmp_path):
    """A World with joints (a hinge, ball joints, one that breaks) and contacts: the
    joint records and their backups are in the schedule's data and buffers, and the C++
    host ends bit for bit where Python does, from the exported capacities and from one
    pair and one manifold (overflows, redos that restore the joints)."""
    world = jointed_scene(runtime)
    world.step(1 / 60)
    world.statistics()
    out = tmp_path / "joints"
    export_world(world, out, build=lambda: jointed_scene(runtime))
    buffers = {b["name"]: b for b in json.loads((out / "schedule.json").read_text())["buffers"]}
    records = np.fromfile(
        out / buffers["joints"]["init"]["file"], rbgen.layouts.JOINT_CONSTRAINT.dtype
    )
    np.testing.assert_array_equal(records, jointed_scene(runtime)._joints.host)
    assert buffers["joint_pairs"]["init"]["kind"] == "data"
    python = jointed_scene(runtime)
    for _ in range(60):
        python.step(1 / 60)
    assert python.joints_broken.tolist() == [False] * 10 + [True, False]
    assert python.statistics()["contacts"] > 0
    expected = [
        python.positions,
        python.orientations,
        python.linear_velocities,
        python.angular_velocities,
    ]
    for options in ([], ["--capacity", "pairs=0", "--capacity", "manifolds=0"]):
        done = run(rbgen_run, out, 60, *options, "--dump", str(tmp_path / "state.bin"))
        assert done.returncode == 0, done.stdout + done.stderr
        assert (overflows(done.stdout) >= 1) == bool(options)
        assert_same(dumped_state(tmp_path / "state.bin", python.body_count), expected)
