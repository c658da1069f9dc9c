"""The public API is documented: every callable in ``drivesense.__all__`` (and the estimators'
public methods) has a docstring naming each of its parameters (python-control's rule)."""

from __future__ import annotations

import inspect
import subprocess
import sys

import pytest

import drivesense as ds


def _public_callables():
    for name in ds.__all__:
        obj = getattr(ds, name)
        if inspect.isclass(obj):
            yield name, obj
            for mname, member in vars(obj).items():
                if mname.startswith("_") or not callable(member):
                    continue
                yield f"{name}.{mname}", member
        elif inspect.isfunction(obj):
            yield name, obj


def _documented(obj) -> list[str]:
    """Parameters of ``obj`` missing from its docstring (or its class's docstring)."""
    target = obj.__init__ if inspect.isclass(obj) else obj
    if isinstance(target, (classmethod, staticmethod)):
        target = target.__func__
    try:
        sig = inspect.signature(target)
    except (TypeError, ValueError):
        return []
    doc = (inspect.getdoc(obj) or "") + "\n" + (inspect.getdoc(target) or "")
    missing = []
    for p in sig.parameters.values():
        if p.name in ("self", "cls") or p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
            continue
        if p.name not in doc:
            missing.append(p.name)
    return missing


@pytest.mark.parametrize("name, obj", list(_public_callables()), ids=lambda v: v if isinstance(v, str) else "")
def test_public_callable_documents_every_parameter(name, obj):
    assert inspect.getdoc(obj), f"{name} has no docstring"
    missing = _documented(obj)
    # estimator subclasses document their constructor on the shared base class
    if missing and inspect.isclass(obj) and issubclass(obj, ds.estimate.BallScrewEstimator):
        missing = [m for m in missing if m not in inspect.getdoc(ds.estimate.BallScrewEstimator)]
    assert not missing, f"{name}: undocumented parameter(s) {missing}"


def test_import_has_no_side_effects():
    """Importing drivesense neither imports pyplot/torch nor adds warnings filters of its own."""
    code = ("import sys, warnings, numpy, scipy.signal, scipy.optimize, xarray, numba, typer, rich; "
            "before = list(warnings.filters); import drivesense; "
            "assert 'matplotlib.pyplot' not in sys.modules, 'pyplot imported'; "
            "assert 'torch' not in sys.modules, 'torch imported'; "
            "assert list(warnings.filters) == before, 'warnings filters changed'")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_errors_subclass_builtins():
    from drivesense import errors

    for name in errors.__all__:
        cls = getattr(errors, name)
        assert issubclass(cls, errors.DriveSenseError)
        if cls is not errors.DriveSenseError:
            assert any(issubclass(cls, b) for b in (ValueError, KeyError, RuntimeError))
