"""The engine stays easy to change: short functions, few positional parameters, a short per-frame method."""

import ast
from pathlib import Path

ENGINE = Path(__file__).resolve().parents[1] / "harness" / "engine"
MAX_LINES = 60            # any engine function
MAX_POSITIONAL = 6        # parameters without a default keyword, self/cls aside (numba kernels need positions)
MAX_STEP_LINES = 30       # Tracker.step, the per-frame method


def _functions():
    for path in sorted(ENGINE.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                yield path.name, node


def test_engine_functions_are_short_and_take_few_positional_parameters():
    long, wide = [], []
    for name, fn in _functions():
        lines = fn.end_lineno - fn.lineno + 1
        if lines > MAX_LINES:
            long.append(f"{name}:{fn.lineno} {fn.name} ({lines} lines)")
        args = fn.args.posonlyargs + fn.args.args
        positional = len(args) - (1 if args and args[0].arg in ("self", "cls") else 0)
        numba = any("njit" in ast.unparse(d) for d in fn.decorator_list)
        if positional > MAX_POSITIONAL and not numba:
            wide.append(f"{name}:{fn.lineno} {fn.name} ({positional} positional)")
    assert not long, long
    assert not wide, wide


def test_the_per_frame_method_is_short():
    step = next(fn for name, fn in _functions() if name == "tracker.py" and fn.name == "step")
    assert step.end_lineno - step.lineno + 1 <= MAX_STEP_LINES
