"""The schedule file (``schedule.json``, format `FORMAT_VERSION`) and its data files.

`rbgen/host/SCHEDULE.md` describes the format for C++ readers; this module writes it from
an `rbgen.schedule.infer.Inference` and reads numbers back (`evaluate`) as a host does,
so that every number of every recorded step is checked against the file before it is
written.
"""

from __future__ import annotations

import hashlib

from .. import __version__, layouts
from ..errors import RbgenError
from ..guard import MAX_REDOS, STEPS_IN_FLIGHT

FORMAT = "rbgen-schedule"
FORMAT_VERSION = 1
#: a grown capacity's new rung: the smallest power of two >= need + need / 4
HEADROOM = (5, 4)


def _json(value):
    """A recorded number as JSON: bytes as hex, tables element-wise."""
    if isinstance(value, bytes):
        return value.hex()
    if isinstance(value, dict):
        return {"by": value["by"], "values": [_json(v) for v in value["values"]]}
    return value


def evaluate(number, rungs: dict[str, int]):
    """A number of the file at the capacities' rungs (what a host computes)."""
    if isinstance(number, dict):
        return number["values"][rungs[number["by"]]]
    return number


def _pattern(data: bytes) -> bytes | None:
    """The 4-byte (or 1-byte) pattern that ``data`` repeats, if any."""
    for width in (1, 4):
        if len(data) % width == 0 and data == data[:width] * (len(data) // width):
            return data[:width]
    return None


def assemble(inf, programs: dict) -> tuple[dict, dict[str, bytes]]:
    """(schedule, data files by relative path) of an inference; ``programs``: (spec, build
    options) -> the exported .cl file's name."""
    main = inf.main
    used = sorted({key[1] for key in inf.samples if key[0] == "size"})
    new_id = {logical: k for k, logical in enumerate(used)}
    files: dict[str, bytes] = {}
    buffers = []
    for logical in used:
        info = inf.buffers[logical]
        size = inf.number(("size", logical))
        buffers.append(
            {
                "name": info.name or f"buffer{logical}",
                "type": info.ctype,
                "size": size,
                "init": _init(info, size, new_id[logical], files),
                "renew_on": inf.renew_on.get(logical, {}),
            }
        )

    def command(key: tuple, numbers: list) -> dict:
        op = key[0]
        if op == "launch":
            args, n = [], 0
            for arg in key[2]:
                if arg[0] == "buffer":
                    args.append(["b", new_id[arg[1]]])
                elif arg[0] == "null":
                    args.append(["n"])
                else:
                    args.append(["s" if arg[0] == "scalar" else "l", _json(numbers[n])])
                    n += 1
            return {
                "op": "launch",
                "kernel": key[1],
                "args": args,
                "global": _json(numbers[n]),
                "local": _json(numbers[n + 1]),
            }
        if op == "fill":
            return {
                "op": "fill",
                "buffer": new_id[key[1]],
                "pattern": _json(numbers[0]),
                "offset": _json(numbers[1]),
                "size": _json(numbers[2]),
            }
        if op == "copy":
            return {
                "op": "copy",
                "dst": new_id[key[1]],
                "src": new_id[key[2]],
                "dst_offset": _json(numbers[0]),
                "src_offset": _json(numbers[1]),
                "size": _json(numbers[2]),
            }
        return {
            "op": "write",
            "buffer": new_id[key[1]],
            "offset": _json(numbers[0]),
            "data": _json(numbers[1]),
        }

    def commands(kind: str, v: int, listing: list) -> list[dict]:
        return [
            command(key, [inf.number((kind, v, i, j)) for j in range(len(numbers))])
            for i, (key, numbers) in enumerate(listing)
        ]

    variants = [commands("step", v, inf.steps[v]) for v in range(len(inf.variants))]
    undo = [commands("undo", v, inf.undo[v]) for v in range(len(inf.variants))]
    kernels = [{"program": programs[(k.spec, k.options)], "name": k.name} for k in inf.kernels]
    first = main.steps[0].values
    world = main.world
    guard = world._guard
    report_buffer = _logical(main, guard.report.base_data, new_id, "the step report")
    stages = []
    for stage, offset in guard._layout:
        protocol = stage.report_protocol()
        stages.append(
            {
                "name": stage.name,
                "offset": offset,
                "words": stage.report_words,
                "capacities": protocol.get("capacities", {}),
                "fatal": protocol.get("fatal", []),
            }
        )
    owner = {name: s["name"] for s in stages for name in s["capacities"]}
    missing = sorted(set(inf.grown) - set(owner))
    if missing:
        raise RbgenError(
            f"schedule: capacities {missing} are grown by stages that do not "
            f"report their need in the step report"
        )
    body = layouts.BODY
    schedule = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "rbgen_version": __version__,
        "device": _device(world.runtime.traits),
        "dt": main.dt,
        "plan": world.plan.describe(),
        "programs": [],  # (filled by the export: files, build options, hashes)
        "kernels": kernels,
        "capacities": [
            {
                "name": name,
                "initial": first[name].bit_length() - 1,
                "max": inf.max_rungs[name],
                "stage": owner[name],
            }
            for name in inf.grown
        ],
        "followers": [
            {
                "name": name,
                "follows": inf.follow[name]["leader"],
                "at_variants": inf.follow[name]["at"],
            }
            for name in inf.followers
        ],
        "buffers": buffers,
        "steps": {
            "prologue": inf.variants.prologue,
            "cycle": inf.variants.cycle,
            "variants": variants,
            "undo": undo,
        },
        "report": {
            "buffer": report_buffer,
            "words": guard.words,
            "stages": stages,
            "steps_in_flight": STEPS_IN_FLIGHT,
            "max_redos": MAX_REDOS,
            "headroom": list(HEADROOM),
        },
        "bodies": {
            "buffer": _logical(main, world._device.bodies.base_data, new_id, "bodies"),
            "count": world.body_count,
            "stride": body.itemsize,
            "fields": {
                f: body.offset(f)
                for f in (
                    "position",
                    "orientation",
                    "linear_velocity",
                    "angular_velocity",
                    "inv_mass",
                )
            },
        },
        "files": {},
    }
    _check(inf, schedule, new_id)
    return schedule, files


def _logical(main, mem, new_id: dict, what: str) -> int:
    info = main.recorder.buffers.get(mem.int_ptr)
    if info is None or info.index not in new_id:
        raise RbgenError(f"schedule: {what} buffer is used by no recorded command")
    return new_id[info.index]


def _init(info, size, index: int, files: dict) -> dict:
    kind, data = info.init
    if kind == "none":
        return {"kind": "zeros"}
    pattern = _pattern(data)
    if pattern is not None:
        return {"kind": "fill", "pattern": pattern.hex()}
    if isinstance(size, dict):
        raise RbgenError(
            f"schedule: buffer {info.name or index} starts with data of a size "
            f"that depends on {size['by']} (only a repeated pattern can be grown)"
        )
    name = f"data/{index:03d}_{info.name or 'buffer'}.bin"
    files[name] = data
    return {"kind": "data", "file": name}


def _device(traits) -> dict:
    return {
        "fingerprint": traits.fingerprint,
        "platform_name": traits.platform_name,
        "device_name": traits.device_name,
        "vendor": traits.vendor,
        "is_gpu": traits.is_gpu,
        "compute_units": traits.compute_units,
        "wavefront": traits.wavefront,
        "local_mem_size": traits.local_mem_size,
        "max_work_group_size": traits.max_work_group_size,
        "driver_version": traits.driver_version,
        "opencl_version": traits.opencl_version,
    }


def _check(inf, schedule: dict, new_id: dict) -> None:
    """Every recorded number, read back from the schedule at its step's rungs."""
    variants, undo = schedule["steps"]["variants"], schedule["steps"]["undo"]
    for key, samples in inf.samples.items():
        if key[0] == "size":
            number = schedule["buffers"][new_id[key[1]]]["size"]
        else:
            command = (variants if key[0] == "step" else undo)[key[1]][key[2]]
            number = _field(command, key[3])
        for value, s in samples:
            state = inf.states[s]
            got = evaluate(number, state)
            if got != _json(value):
                raise RbgenError(
                    f"schedule: {inf.describe(key)} reads {got!r} from the "
                    f"schedule at {state}, but the step had {_json(value)!r}"
                )


def _field(command: dict, j: int):
    if command["op"] == "launch":
        numbered = [a[1] for a in command["args"] if a[0] in ("s", "l")]
        numbered += [command["global"], command["local"]]
        return numbered[j]
    fields = {
        "fill": ("pattern", "offset", "size"),
        "copy": ("dst_offset", "src_offset", "size"),
        "write": ("offset", "data"),
    }[command["op"]]
    return command[fields[j]]


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()
