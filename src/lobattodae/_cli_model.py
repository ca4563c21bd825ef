"""``lobattodae run --model MODULE:FACTORY``: import the user's factory and make a run target of
what it returns (a tuple, a dict, a mechanics model or an :class:`~lobattodae.examples.Example`);
every mistake is one line, raised as :class:`UsageError` (exit code 2).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["MODEL_HELP", "RunTarget", "UsageError", "from_example", "load_model"]


class UsageError(Exception):
    """A mistake on the command line: its message is printed, the exit code is 2."""


MODEL_HELP = (
    "your own model: MODULE:FACTORY (a module importable from the current directory, or FILE.py:FACTORY); "
    "FACTORY() returns (problem, q0, p0[, args]), a dict with keys problem (or model), q0, p0 (or qdot0 "
    "with a mechanics model) and optionally args, t_span, lam0, invariants, draw, name, or a "
    "lobattodae.examples.Example"
)

#: Keys of the dict a ``--model`` factory may return.
MODEL_KEYS = ("problem", "model", "q0", "p0", "qdot0", "args", "t_span", "lam0", "invariants", "draw", "name")

_MODEL_RETURNS = (
    "(problem, q0, p0) or (problem, q0, p0, args), a dict with keys problem (or model), q0, p0 (or qdot0) "
    "[, args, t_span, lam0, invariants, draw, name], or a lobattodae.examples.Example"
)


@dataclass(frozen=True)
class RunTarget:
    """What ``run`` integrates: a built-in example or the result of a ``--model`` factory."""

    name: str
    problem: Any
    q0: Any
    p0: Any
    lam0: Any = None
    args: Any = None
    t_span: tuple[float, float] | None = None
    invariants: Mapping[str, Any] = field(default_factory=dict)
    draw: Any = None
    labels: tuple[str, ...] | None = None  # coordinate names (a mechanics model's)


def from_example(ex, name=None) -> RunTarget:
    return RunTarget(name=name or ex.name, problem=ex.problem, q0=ex.q0, p0=ex.p0, lam0=ex.lam0, args=ex.args,
                   t_span=ex.t_span, invariants=dict(ex.invariants))


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _import_model_module(spec: str, module_name: str):
    """The module of ``--model``: a dotted name importable with the current directory on
    ``sys.path`` (as ``python -m`` has it), or a ``.py`` file."""
    import importlib
    import importlib.util

    try:
        if module_name.endswith(".py"):
            path = Path(module_name)
            if not path.is_file():
                raise UsageError(f"--model {spec}: no such file {module_name!r}")
            unique = f"_lobattodae_model_{abs(hash(str(path.resolve())))}"
            loader_spec = importlib.util.spec_from_file_location(unique, path)
            module = importlib.util.module_from_spec(loader_spec)
            sys.modules[unique] = module
            try:
                loader_spec.loader.exec_module(module)
            except BaseException:
                del sys.modules[unique]
                raise
            return module
        return importlib.import_module(module_name)
    except UsageError:
        raise
    except (Exception, SystemExit) as exc:  # ImportError, SyntaxError, whatever the module raised at import
        hint = ""
        if isinstance(exc, ModuleNotFoundError) and exc.name and module_name.split(".")[0] == exc.name.split(".")[0]:
            hint = " (run lobattodae from the directory that contains it, or add that directory to PYTHONPATH)"
        raise UsageError(f"--model {spec}: cannot import {module_name!r}: {_one_line(exc)}{hint}") from None


def _mechanics_model_class():
    """:class:`lobattodae.mechanics.LagrangianModel` if the mechanics front end is loaded (a
    factory that returns one has loaded it), else None (SymPy is not imported for nothing)."""
    module = sys.modules.get("lobattodae.mechanics._model")
    return getattr(module, "LagrangianModel", None)


def load_model(spec: str) -> RunTarget:
    """Import ``MODULE:FACTORY``, call the factory and check what it returned."""
    module_name, sep, attr = spec.rpartition(":")
    if not sep or not module_name or not attr or not all(part.isidentifier() for part in attr.split(".")):
        raise UsageError(
            f"--model must be MODULE:FACTORY (e.g. mymodels:sleigh for the function sleigh in mymodels.py, "
            f"or path/to/file.py:sleigh); got {spec!r}"
        )
    # the current directory (as ``python -m`` has it) and a FILE.py's own directory (as ``python
    # FILE.py`` has it) are on sys.path while the module is imported and the factory runs
    places = [os.getcwd()]
    if module_name.endswith(".py"):
        places.append(str(Path(module_name).resolve().parent))
    added = [d for d in dict.fromkeys(places) if d not in sys.path]
    sys.path[:0] = added
    try:
        module = _import_model_module(spec, module_name)
        factory = module
        for part in attr.split("."):
            if not hasattr(factory, part):
                names = sorted(k for k, v in vars(module).items() if callable(v) and not k.startswith("_"))
                listed = ", ".join(names[:12]) + (", ..." if len(names) > 12 else "")
                raise UsageError(
                    f"--model {spec}: module {module_name!r} ({getattr(module, '__file__', '?')}) has no attribute "
                    f"{attr!r}; its functions: {listed or 'none'}"
                )
            factory = getattr(factory, part)
        if not callable(factory):
            raise UsageError(f"--model {spec}: {attr!r} is a {type(factory).__name__}, not a function; "
                              f"point at a function without arguments that returns {_MODEL_RETURNS}")
        try:
            returned = factory()
        except (Exception, SystemExit) as exc:
            raise UsageError(f"--model {spec}: the factory {attr}() raised {_one_line(exc)}") from None
    finally:
        for d in added:
            if d in sys.path:
                sys.path.remove(d)
    return _target_of(spec, attr, returned)


def _wrong(spec, what: str) -> UsageError:
    return UsageError(f"--model {spec}: the factory returned {what}; return {_MODEL_RETURNS}")


def _describe(value) -> str:
    text = repr(value)
    return f"{type(value).__name__} {text if len(text) <= 60 else text[:57] + '...'}"


def _target_of(spec: str, attr: str, returned) -> RunTarget:
    """The :class:`RunTarget` of a factory's return value (or a usage error saying what is wrong)."""
    from .examples import Example

    if isinstance(returned, Example):
        return from_example(returned)
    model_class = _mechanics_model_class()
    if model_class is not None and isinstance(returned, model_class):
        raise UsageError(
            f"--model {spec}: the factory returned a mechanics model ({returned.name}) without initial values; "
            "return (model, q0, p0, args) or dict(model=model, q0=..., qdot0=..., args=model.args(...))"
        )
    if isinstance(returned, Mapping):
        unknown = [k for k in returned if k not in MODEL_KEYS]
        if unknown:
            raise _wrong(spec, f"a dict with unknown keys {unknown} (allowed: {', '.join(MODEL_KEYS)})")
        if ("problem" in returned) == ("model" in returned):
            raise _wrong(spec, "a dict with " + ("both 'problem' and 'model'" if "problem" in returned
                                                 else "neither 'problem' nor 'model'"))
        if "q0" not in returned or ("p0" in returned) == ("qdot0" in returned):
            raise _wrong(spec, "a dict without 'q0'" if "q0" not in returned else
                         "a dict with " + ("both 'p0' and 'qdot0'" if "p0" in returned else "neither 'p0' nor 'qdot0'"))
        fields = dict(returned)
        obj = fields.pop("problem") if "problem" in fields else fields.pop("model")
    elif isinstance(returned, tuple) and len(returned) in (3, 4):
        obj, q0, p0, *rest = returned
        fields = {"q0": q0, "p0": p0, "args": rest[0] if rest else None}
    else:
        raise _wrong(spec, _describe(returned) if not isinstance(returned, tuple) else f"a tuple of {len(returned)}")

    name = fields.get("name") or attr
    args = fields.get("args")
    if model_class is not None and isinstance(obj, model_class):
        model = obj
        problem = model.problem
        name = fields.get("name") or model.name
        try:
            args = model.args(args) if args is None or isinstance(args, Mapping) else args
        except (ValueError, TypeError) as exc:
            raise UsageError(f"--model {spec}: the model's parameters: {_one_line(exc)}") from None
    else:
        model, problem = None, obj
        if not all(callable(getattr(problem, a, None)) for a in ("f", "g", "phi")):
            raise _wrong(spec, f"{_describe(problem)} where the problem goes (a PartitionedDAE, NonholonomicSystem, "
                               "MechanicalSystem or mechanics model is needed)")
    t_span = fields.get("t_span")
    if t_span is not None:
        try:
            t_span = tuple(float(v) for v in t_span)
            if len(t_span) != 2:
                raise ValueError
        except (TypeError, ValueError):
            raise _wrong(spec, f"t_span {t_span!r} (it must be a pair of numbers (t0, t1))") from None
    q0 = fields["q0"]
    p0 = fields.get("p0")
    if p0 is None and "qdot0" in fields:
        if model is None:
            raise _wrong(spec, "qdot0 with a problem that is not a mechanics model (give p0, the momenta)")
        try:
            p0 = model.momenta(t_span[0] if t_span else 0.0, q0, fields["qdot0"], args)
        except (ValueError, TypeError) as exc:
            raise UsageError(f"--model {spec}: the momenta of qdot0: {_one_line(exc)}") from None
    for key, value in (("q0", q0), ("p0", p0)):
        try:
            a = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            a = None
        if a is None or a.ndim != 1 or a.size == 0:
            raise _wrong(spec, f"{key} = {_describe(value)} (it must be a 1-D array of numbers)")
    invariants = fields.get("invariants")
    if invariants is None:
        ham = getattr(problem, "hamiltonian", None)
        invariants = {"energy": ham} if callable(ham) else {}
    elif not isinstance(invariants, Mapping) or not all(callable(v) for v in invariants.values()):
        raise _wrong(spec, "invariants that are not a dict of functions I(t, q, p, args)")
    draw = fields.get("draw")
    if draw is not None and not callable(draw):
        raise _wrong(spec, f"draw = {_describe(draw)} (it must be a function draw(t, q, args) -> shapes)")
    labels = tuple(str(c) for c in model.coordinate_names) if model is not None else None
    return RunTarget(name=str(name), problem=problem, q0=q0, p0=p0, lam0=fields.get("lam0"), args=args,
                   t_span=t_span, invariants=dict(invariants), draw=draw, labels=labels)
