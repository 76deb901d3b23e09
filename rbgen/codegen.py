"""Kernel generation: Mako templates specialised by parameters, built and cached.

A `KernelTemplate` names a template file under ``rbgen/templates/`` and declares
its parameters (each with the values it allows and why it exists). Calling
``template.spec(**values)`` validates them and returns a `KernelSpec`: a pure,
hashable description whose rendered source is always the same text.

A kernel's arguments may be declared once, in Python, as a `Signature` (an ordered
list of typed `Arg` entries, each with the specialisations that have it, as pyopencl
declares a kernel's arguments): the template renders it as the kernel's parameter list
(``void name(${signature("name")})``) and the launcher binds values to it by name
(`Signature.binder`), so the signature and the binding cannot disagree.

`build` turns a spec into a `cl.Program` once per (source, device, options):
programs are cached in memory and their binaries on disk (``RBGEN_CACHE_DIR``,
default ``~/.cache/rbgen``), so a second process starts without compiling. A
build error raises `KernelBuildError` with the spec, the compiler log and the
offending generated lines, numbered.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import re
import threading
from collections.abc import Callable, Iterable, Mapping
from functools import lru_cache
from pathlib import Path
from typing import Any, cast

import pyopencl as cl
from mako.lookup import TemplateLookup

from . import layouts
from .device import Runtime, is_pocl
from .errors import KernelBuildError, TemplateParameterError
from .progress import build_feedback

TEMPLATE_DIR = Path(__file__).parent / "templates"
ENV_CACHE_DIR = "RBGEN_CACHE_DIR"


def cache_dir() -> Path:
    """Root of rbgen's on-disk caches (programs, tuning)."""
    root = os.environ.get(ENV_CACHE_DIR)
    if root:
        return Path(root)
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "rbgen"


# --------------------------------------------------------------------------
# Templates and specs


@dataclasses.dataclass(frozen=True)
class Param:
    """One specialisation parameter of a template.

    ``allowed`` is a tuple of permitted values, or a predicate with
    ``allowed_text`` describing it (e.g. "a power of two <= 1024").
    """

    name: str
    allowed: tuple | Callable[[Any], bool]
    doc: str
    allowed_text: str = ""

    def check(self, value: Any, where: str) -> None:
        if callable(self.allowed):
            ok = self.allowed(value)
            text = self.allowed_text or "the allowed set"
        else:
            ok = value in self.allowed and type(value) in {type(a) for a in self.allowed}
            text = f"one of {list(self.allowed)}"
        if not ok:
            raise TemplateParameterError(
                f"{where}: parameter {self.name}={value!r} is not allowed; expected {text}"
            )


def power_of_two(lo: int = 1, hi: int = 1 << 16) -> Callable[[Any], bool]:
    return lambda v: isinstance(v, int) and lo <= v <= hi and (v & (v - 1)) == 0


def work_group_size_param(doc: str) -> Param:
    """The ``work_group_size`` parameter most kernels take: a power of two up to 1024
    (the largest work group OpenCL devices commonly allow). ``doc`` says what one
    work-item of this kernel handles and why the size matters."""
    return Param("work_group_size", power_of_two(1, 1024), doc, "a power of two from 1 to 1024")


@dataclasses.dataclass(frozen=True)
class Arg:
    """One kernel argument: its OpenCL C type, its name, and the specialisations that
    have it. ``ctype``: the type's text, or a function of the template values that
    returns it (an address space that depends on a parameter); ``when``: a predicate on
    the template values (None: every specialisation has the argument)."""

    ctype: str | Callable[[Mapping[str, Any]], str]
    name: str
    when: Callable[[Mapping[str, Any]], bool] | None = None

    def wanted(self, values: Mapping[str, Any]) -> bool:
        return self.when is None or bool(self.when(values))

    def type_for(self, values: Mapping[str, Any]) -> str:
        return self.ctype(values) if callable(self.ctype) else self.ctype


class Signature:
    """The arguments of one kernel, in order, declared once (see the module docstring).

    `render` writes the parameter list a specialisation's template puts between the
    kernel's parentheses; `binder` makes the launcher's setter of a set of arguments, by
    name, at their positions in that list. Both read the same declaration.
    """

    def __init__(self, kernel: str, args: Iterable[Arg]):
        self.kernel = kernel
        self.declared = tuple(args)
        names = [a.name for a in self.declared]
        if len(set(names)) != len(names):
            raise TemplateParameterError(
                f"kernel {kernel}: an argument is declared twice in {names}"
            )
        self._cache: dict[tuple, tuple[Arg, ...]] = {}

    def args(self, values: Mapping[str, Any]) -> tuple[Arg, ...]:
        """The arguments a specialisation with these template values has, in order."""
        key = tuple(sorted(values.items()))
        found = self._cache.get(key)
        if found is None:
            found = self._cache[key] = tuple(a for a in self.declared if a.wanted(values))
        return found

    def render(self, values: Mapping[str, Any]) -> str:
        """The parameter list, one argument a line, aligned under the first (the template
        writes ``void <kernel>(`` at the start of a line, then this)."""
        indent = "\n" + " " * len(f"void {self.kernel}(")
        return ("," + indent).join(f"{a.type_for(values)} {a.name}" for a in self.args(values))

    def binder(self, spec: KernelSpec, *names: str) -> Binder:
        """A setter of the arguments ``names`` (in that order) of ``spec``'s kernel. A name
        the declaration lacks, or that this specialisation does not have, is refused,
        naming it."""
        values = spec.values
        args = self.args(values)
        position = {a.name: i for i, a in enumerate(args)}
        for name in names:
            if name not in position:
                known = [a.name for a in self.declared]
                why = (
                    f"is not an argument of this specialisation ({spec})"
                    if name in known
                    else f"is not declared; arguments: {known}"
                )
                raise TemplateParameterError(f"kernel {self.kernel}: {name!r} {why}")
        return Binder(self.kernel, len(args), [position[n] for n in names])

    def check_bound(self, spec: KernelSpec, *binders: Binder) -> None:
        """Refuse a set of binders that leaves an argument of ``spec``'s kernel unset (the
        launcher's whole binding, checked once, when it is built)."""
        bound = {i for b in binders for i in b.positions}
        args = self.args(spec.values)
        missing = [a.name for i, a in enumerate(args) if i not in bound]
        if missing:
            raise TemplateParameterError(
                f"kernel {self.kernel}: the launcher never sets {missing} ({spec})"
            )


class Binder:
    """Sets some arguments of a kernel at their declared positions (`Signature.binder`):
    ``binder(kernel, *values)`` with a `rbgen.launch.BoundKernel`, values in the order
    of the binder's names; only the changed ones reach the driver."""

    __slots__ = ("kernel_name", "arg_count", "positions", "_runs")

    def __init__(self, kernel_name: str, arg_count: int, positions: list[int]):
        self.kernel_name = kernel_name
        self.arg_count = arg_count
        self.positions = tuple(positions)
        # runs of consecutive positions: (first position, first value, value count)
        runs: list[list[int]] = []
        for k, p in enumerate(positions):
            if runs and p == runs[-1][0] + runs[-1][2]:
                runs[-1][2] += 1
            else:
                runs.append([p, k, 1])
        self._runs = tuple(tuple(r) for r in runs)

    def __call__(self, kernel, *values) -> None:
        if len(values) != len(self.positions):
            raise TypeError(
                f"kernel {self.kernel_name}: {len(self.positions)} values "
                f"expected, got {len(values)}"
            )
        if kernel.num_args != self.arg_count:
            raise TemplateParameterError(
                f"kernel {self.kernel_name} was built with {kernel.num_args} arguments, its "
                f"declaration has {self.arg_count}: its template does not render the "
                f"declared signature"
            )
        for first, start, count in self._runs:
            kernel.bind_at(first, *values[start : start + count])


#: every KernelTemplate by path (filled as modules are imported; export uses it)
TEMPLATES: dict[str, KernelTemplate] = {}


class KernelTemplate:
    """A template file plus the parameters that specialise it."""

    def __init__(
        self,
        path: str,
        params: Iterable[Param],
        doc: str = "",
        roles: Mapping[str, str] | None = None,
        defaults: Callable[[Any], dict] | None = None,
        requires: Callable[[dict], str | None] | None = None,
        build_options: Callable[[dict], Iterable[str]] | None = None,
        signatures: Iterable[Signature] = (),
    ):
        self.path = path
        self.params = {p.name: p for p in params}
        self.doc = doc
        #: argument roles that cannot be read off the signature ("inout"...)
        self.roles = dict(roles or {})
        #: heuristic parameters for a device: ``defaults(traits) -> {name: value}``
        #: (what an untuned device gets, and what `rbgen export` renders by default)
        self._defaults = defaults
        #: rules between parameters: ``requires(values)`` says what is wrong, or None
        self._requires = requires
        #: compiler options a specialisation needs: ``build_options(values) -> [option, ...]``
        #: (part of the program cache key and of the export manifest, so that a program
        #: built outside rbgen is the one rbgen runs)
        self._build_options = build_options
        #: kernel name -> its declared arguments (the template renders them with
        #: ``${signature("name")}``)
        self.signatures = {sig.kernel: sig for sig in signatures}
        if not (TEMPLATE_DIR / path).is_file():
            raise TemplateParameterError(f"template {path!r} not found under {TEMPLATE_DIR}")
        TEMPLATES[path] = self

    def default_spec(self, traits, **overrides: Any) -> KernelSpec:
        """The heuristic specialisation for a device, with optional overrides."""
        if self._defaults is None:
            raise TemplateParameterError(
                f"template {self.path} declares no defaults; "
                f"give every parameter: {sorted(self.params)}"
            )
        return self.spec(**{**self._defaults(traits), **overrides})

    def spec(self, **values: Any) -> KernelSpec:
        where = f"template {self.path}"
        unknown = sorted(set(values) - set(self.params))
        if unknown:
            raise TemplateParameterError(
                f"{where}: unknown parameter(s) {unknown}; declared: {sorted(self.params)}"
            )
        missing = sorted(set(self.params) - set(values))
        if missing:
            raise TemplateParameterError(f"{where}: missing parameter(s) {missing}")
        for name, value in values.items():
            self.params[name].check(value, where)
        problem = self._requires(values) if self._requires else None
        if problem:
            raise TemplateParameterError(f"{where}: {problem}")
        return KernelSpec(self.path, tuple(sorted(values.items())), self)

    def build_options(self, values: Mapping[str, Any]) -> tuple[str, ...]:
        """The compiler options a specialisation with these values is built with."""
        return tuple(self._build_options(dict(values))) if self._build_options else ()

    def source_hash(self) -> str:
        """Hash of this template and the templates it uses."""
        return template_source_hash(self.path)

    def __repr__(self) -> str:
        return f"KernelTemplate({self.path!r}, params={sorted(self.params)})"


@dataclasses.dataclass(frozen=True)
class KernelSpec:
    """A template path and its validated parameters: pure, hashable."""

    path: str
    params: tuple[tuple[str, Any], ...]
    template: KernelTemplate | None = dataclasses.field(default=None, compare=False, repr=False)

    @property
    def values(self) -> dict[str, Any]:
        return dict(self.params)

    @property
    def source(self) -> str:
        return render(self.path, self.params)

    @property
    def source_hash(self) -> str:
        return hashlib.sha256(self.source.encode()).hexdigest()

    @property
    def build_options(self) -> tuple[str, ...]:
        """The compiler options the template asks for with these values."""
        return self.template.build_options(self.values) if self.template is not None else ()

    def __str__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.params)
        return f"{self.path}({args})"


@lru_cache(maxsize=1)
def _lookup() -> TemplateLookup:
    return TemplateLookup(
        directories=[str(TEMPLATE_DIR)], strict_undefined=True, input_encoding="utf-8"
    )


def _render_globals() -> dict[str, Any]:
    """Names every template may use besides its own parameters."""
    return {
        "cl_structs": layouts.cl_structs,
        "cl_constants": layouts.cl_constants,
    }


@lru_cache(maxsize=512)
def render(path: str, params: tuple[tuple[str, Any], ...]) -> str:
    """Render a template with parameters; pure and cached."""
    template = _lookup().get_template(path)
    values = dict(params)
    text = template.render(
        **_render_globals(), signature=_signature_renderer(path, values), **values
    )
    return _tidy(text)


def _signature_renderer(path: str, values: dict) -> Callable[[str], str]:
    """The template's ``signature(kernel)``: the parameter list of a kernel its
    KernelTemplate declares (an undeclared kernel fails at render time, naming it)."""
    declared = TEMPLATES[path].signatures if path in TEMPLATES else {}

    def signature(kernel: str) -> str:
        if kernel not in declared:
            raise TemplateParameterError(
                f"template {path} declares no signature for kernel "
                f"{kernel!r}; declared: {sorted(declared)}"
            )
        return declared[kernel].render(values)

    return signature


def _tidy(text: str) -> str:
    """Collapse the blank-line runs that template control flow leaves behind."""
    text = re.sub(r"[ \t]+\n", "\n", text)
    text = re.sub(r"\n{3,}", "\n\n", text)
    return text.strip() + "\n"


#: a template's use of another: <%include file="..."/> or <%namespace ... file="..."/>
_USES = re.compile(r'<%(?:include|namespace)\b[^>]*?\bfile="/?([^"]+)"')


def template_sources(path: str) -> list[str]:
    """A template and every template it includes or imports, directly or not (paths under
    the template directory, each once, the template first). An include whose file is an
    expression (``file="/${...}"``: a shape type's file, chosen by a parameter) cannot be
    followed here; the rendered source, and so its hash, still contains it."""
    seen, pending = [], [path]
    while pending:
        current = pending.pop(0)
        if current in seen:
            continue
        seen.append(current)
        text = (TEMPLATE_DIR / current).read_text(encoding="utf-8")
        pending += [used for used in _USES.findall(text) if "${" not in used]
    return seen


def template_source_hash(path: str) -> str:
    """Hash of a template's text, the templates it uses and the struct header: what
    its rendered source can depend on besides its parameters."""
    h = hashlib.sha256()
    for source in template_sources(path):
        h.update(source.encode())
        h.update((TEMPLATE_DIR / source).read_bytes())
    h.update(layouts.c_header().encode())
    return h.hexdigest()[:16]


# --------------------------------------------------------------------------
# Building and caching programs


def driver_caches_kernels(device: cl.Device) -> bool:
    """Whether ``device``'s driver keeps compiled kernels on disk itself, so that
    `ProgramCache` keeps no binaries of its own for it: PoCL (pyopencl's bundled build and
    the system's) caches every program and compiled kernel by source and options, and,
    asked for a program's binary, generates code for all of its kernels beyond what the
    launches compile (for a persistent solver's program, minutes of a small CPU's time),
    which a second run, served from PoCL's cache, does not need."""
    return is_pocl(device)


class ProgramCache:
    """Built programs by (source hash, device fingerprint, options).

    Memory first, then binaries on disk (not for a driver that caches its own,
    `driver_caches_kernels`). A corrupt or stale binary is ignored and rebuilt
    from source. ``stats`` counts hits for tests and reports.
    """

    def __init__(self, directory: Path | None = None):
        self._directory = directory
        self._memory: dict[tuple, cl.Program] = {}
        self._lock = threading.Lock()
        self.stats = {"memory_hits": 0, "disk_hits": 0, "builds": 0}

    @property
    def directory(self) -> Path:
        return self._directory or (cache_dir() / "programs")

    def key(self, runtime: Runtime, source: str, options: tuple[str, ...]) -> str:
        text = "\0".join([source, runtime.traits.fingerprint, *options])
        return hashlib.sha256(text.encode()).hexdigest()[:32]

    def build(
        self,
        runtime: Runtime,
        source: str,
        options: tuple[str, ...] = (),
        spec: KernelSpec | None = None,
    ) -> cl.Program:
        key = self.key(runtime, source, options)
        mem_key = (key, id(runtime.context))
        with self._lock:
            program = self._memory.get(mem_key)
            if program is not None:
                self.stats["memory_hits"] += 1
                return program
        binaries = not driver_caches_kernels(runtime.device)
        program = self._from_disk(runtime, key, options) if binaries else None
        if program is not None:
            self.stats["disk_hits"] += 1
        else:
            with build_feedback(spec.path if spec is not None else "generated source"):
                program = self._from_source(runtime, source, options, spec)
            self.stats["builds"] += 1
            if binaries:
                self._to_disk(program, key)
        with self._lock:
            self._memory[mem_key] = program
        return program

    def _from_disk(self, runtime: Runtime, key: str, options) -> cl.Program | None:
        path = self.directory / f"{key}.bin"
        if not path.is_file():
            return None
        try:
            binary = path.read_bytes()
            program = cl.Program(runtime.context, [runtime.device], [binary])
            program.build(options=list(options))
            return program
        except (cl.Error, OSError):
            return None

    def _to_disk(self, program: cl.Program, key: str) -> None:
        try:
            binary = cast("list[bytes]", program.get_info(cl.program_info.BINARIES))[0]
            if not binary:
                return
            self.directory.mkdir(parents=True, exist_ok=True)
            tmp = self.directory / f"{key}.{os.getpid()}.tmp"
            tmp.write_bytes(binary)
            os.replace(tmp, self.directory / f"{key}.bin")
        except (cl.Error, OSError):
            pass  # a cache that cannot be written only costs a rebuild

    @staticmethod
    def _from_source(runtime, source, options, spec) -> cl.Program:
        program = cl.Program(runtime.context, source)
        try:
            # pyopencl's own cache takes False (off); Program.build's annotation leaves it out
            program.build(options=list(options), cache_dir=False)  # type: ignore[arg-type]
        except cl.RuntimeError as err:
            log = _build_log(program, runtime) or str(err)
            raise KernelBuildError(_format_build_error(source, log, spec, options)) from None
        return program


def _build_log(program: cl.Program, runtime: Runtime) -> str:
    try:
        return program.get_build_info(runtime.device, cl.program_build_info.LOG)
    except cl.Error:
        return ""


def _format_build_error(source: str, log: str, spec, options) -> str:
    lines = source.splitlines()
    bad = sorted(
        {
            int(m.group(1))
            for line in log.splitlines()
            if "error" in line
            for m in [re.search(r":(\d+):\d+:", line)]
            if m
        }
    )
    shown = []
    for n in bad[:8]:
        lo, hi = max(1, n - 2), min(len(lines), n + 2)
        for i in range(lo, hi + 1):
            mark = ">>" if i == n else "  "
            shown.append(f"{mark}{i:5d} | {lines[i - 1]}")
        shown.append("   ...")
    what = str(spec) if spec is not None else "(raw source)"
    return (
        f"OpenCL build failed for {what} with options {list(options)}\n"
        f"--- compiler log ---\n{log.strip()}\n"
        f"--- offending generated source ---\n" + ("\n".join(shown) or "(no line numbers in log)")
    )


PROGRAMS = ProgramCache()


class Compiled:
    """A built spec with its kernels, created once (kernel objects are reused)."""

    def __init__(self, runtime: Runtime, spec: KernelSpec, options: tuple[str, ...] = ()):
        self.runtime = runtime
        self.spec = spec
        self.program = PROGRAMS.build(runtime, spec.source, options, spec)
        self._kernels: dict[str, cl.Kernel] = {}

    def kernel(self, name: str) -> cl.Kernel:
        k = self._kernels.get(name)
        if k is None:
            names = kernel_names(self.spec.source)
            if name not in names:
                raise TemplateParameterError(
                    f"{self.spec} has no kernel {name!r}; kernels: {names}"
                )
            k = self._kernels[name] = getattr(self.program, name)
        return k

    def __getattr__(self, name: str) -> cl.Kernel:
        if name.startswith("_"):
            raise AttributeError(name)
        return self.kernel(name)


_COMPILED: dict[tuple, Compiled] = {}


def compile_spec(runtime: Runtime, spec: KernelSpec, options: Iterable[str] = ()) -> Compiled:
    """Build (or fetch) ``spec`` for ``runtime``, with the spec's own build options and then
    ``options``; the result is shared."""
    options = spec.build_options + tuple(o for o in options if o not in spec.build_options)
    key = (id(runtime), spec, options)
    c = _COMPILED.get(key)
    if c is None or c.runtime is not runtime:
        c = _COMPILED[key] = Compiled(runtime, spec, options)
    for log in runtime.spec_logs:
        log.setdefault((spec, options), None)
    return c


#: what `kernel_resources` reads of each kernel (clGetKernelWorkGroupInfo), by its name there
RESOURCE_QUERIES = (
    ("max_work_group_size", cl.kernel_work_group_info.WORK_GROUP_SIZE),
    ("private_mem_bytes", cl.kernel_work_group_info.PRIVATE_MEM_SIZE),
    ("local_mem_bytes", cl.kernel_work_group_info.LOCAL_MEM_SIZE),
    ("work_group_multiple", cl.kernel_work_group_info.PREFERRED_WORK_GROUP_SIZE_MULTIPLE),
)


def kernel_resources(
    runtime: Runtime, spec: KernelSpec, options: Iterable[str] = ()
) -> dict[str, dict[str, int]]:
    """What the device's compiler made of each kernel of ``spec`` built with ``options``
    (as `compile_spec` builds it; a build rbgen already made is not repeated), by kernel
    name: the largest work group it can run (on a GPU, its registers a work-item bound
    it: 256 on NVIDIA means more than 128), a work-item's private memory (on NVIDIA the
    registers it spilled and its stack), a work group's local memory, and the preferred
    multiple of the work-group size (the warp or wavefront on GPUs). A kernel that needs
    more registers than its launch allows fails to launch; one that spills pays for it in
    every dependent chain."""
    compiled = compile_spec(runtime, spec, options)
    device = runtime.device
    return {
        name: {
            key: int(cast(int, compiled.kernel(name).get_work_group_info(query, device)))
            for key, query in RESOURCE_QUERIES
        }
        for name in kernel_names(spec.source)
    }


class SpecLog:
    """Every (spec, build options) compiled on one runtime for one owner, in first-use
    order.

    While active (``with log:``), each `compile_spec` on that runtime adds its spec and
    options, cached builds included: so the log holds exactly what the owner runs
    (`rbgen export --world` writes it)."""

    def __init__(self, runtime: Runtime):
        self.runtime = runtime
        self.entries: dict[tuple, None] = {}

    def __enter__(self) -> SpecLog:
        self.runtime.spec_logs.append(self.entries)
        return self

    def __exit__(self, *exc) -> None:
        # by identity: two logs may hold equal entries (list.remove compares values)
        logs = self.runtime.spec_logs
        del logs[next(i for i, log in enumerate(logs) if log is self.entries)]

    def specs(self) -> list[tuple[KernelSpec, tuple[str, ...]]]:
        return list(self.entries)


# --------------------------------------------------------------------------
# Kernel signatures (for the export manifest)

_KERNEL_RE = re.compile(
    r"__kernel\s+(?:__attribute__\s*\(\(.*?\)\)\s*)*void\s+(\w+)\s*\(([^)]*)\)", re.S
)


def kernel_names(source: str) -> list[str]:
    return [m.group(1) for m in _KERNEL_RE.finditer(source)]


def kernel_signatures(source: str, roles: Mapping[str, str] | None = None) -> dict[str, list[dict]]:
    """Arguments of every kernel: name, C type and role.

    Roles: ``input`` (``__global const``), ``output`` (``__global`` not const,
    unless the template declares ``inout``), ``local`` (``__local``) and
    ``scalar`` (by value).
    """
    roles = roles or {}
    out = {}
    for m in _KERNEL_RE.finditer(source):
        args = []
        for raw in m.group(2).split(","):
            raw = " ".join(raw.split())
            if not raw:
                continue
            name = re.findall(r"\w+", raw)[-1]
            ctype = raw[: raw.rfind(name)].strip()
            if "__local" in ctype or "local " in ctype:
                role = "local"
            elif "__global" in ctype or "global " in ctype:
                role = "input" if "const" in ctype.split("*")[0] else "output"
            else:
                role = "scalar"
            args.append({"name": name, "type": ctype, "role": roles.get(name, role)})
        out[m.group(1)] = args
    return out
