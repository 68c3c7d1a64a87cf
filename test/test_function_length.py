"""Every function of the package fits on a screen (the architecture's rule, issue 18)."""

import ast
import pathlib

#: Longest function, in lines from ``def`` to its last line, docstring included.
SCREEN_LINES = 60
PACKAGE = pathlib.Path(__file__).resolve().parent.parent / 'dcmotor_id'
#: Functions allowed to be longer, with the reason.  Numba kernels are one loop over the samples
#: each: a call per sample into a helper costs the compiled loop its speed (numba inlines only
#: what it is told to), so their bodies stay whole.
LONGER = {
    'dcmotor_id/simulation/kernels.py:simulate_kernel': 'numba kernel',
    'dcmotor_id/simulation/kernels.py:_brush_step': 'numba kernel',
    'dcmotor_id/simulation/kernels.py:effects_kernel': 'numba kernel',
    'dcmotor_id/simulation/sensitivity.py:flow_matrices': 'numba kernel',
    'dcmotor_id/simulation/sensitivity.py:_event_step_sens': 'numba kernel',
    'dcmotor_id/simulation/sensitivity.py:normal_kernel': 'numba kernel',
}


def _long_functions():
    for path in sorted(PACKAGE.rglob('*.py')):
        tree = ast.parse(path.read_text(encoding='utf-8'))
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = node.end_lineno - node.lineno + 1
                if lines > SCREEN_LINES:
                    yield f'{path.relative_to(PACKAGE.parent).as_posix()}:{node.name}', lines


def test_functions_fit_on_a_screen():
    """No function is longer than a screen unless the allowance names it and why."""
    long = dict(_long_functions())
    unexpected = {name: lines for name, lines in long.items() if name not in LONGER}
    assert not unexpected, f'functions over {SCREEN_LINES} lines: {unexpected}'


def test_allowances_are_still_needed():
    """An allowance for a function that is now short (or gone) is removed, not kept."""
    long = dict(_long_functions())
    stale = sorted(set(LONGER) - set(long))
    assert not stale, f'allowances no longer needed: {stale}'
