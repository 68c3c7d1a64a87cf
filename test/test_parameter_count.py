"""Long parameter lists in identification/ become option objects or state (issue 28)."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent / 'dcmotor_id' / 'identification'
#: Functions kept with 8 or more parameters, and why.
KEPT = {
    'identify.py:identify': 'the public keyword arguments of identify() (a contract)',
    'estimators/refined.py:__init__': "RefinedEstimator's public options, each a keyword",
    'error_model/residuals.py:one_step_error': 'public keywords, one per effect contribution',
    'estimators/least_squares.py:levenberg_marquardt': 'the numerical core: distinct inputs',
    'estimators/least_squares.py:__init__': 'FitProblem: the numerical core, distinct inputs',
    'estimators/fisher.py:cramer_rao_bound': 'public: the experiment design calls it',
}


def _long_parameter_lists(root: Path, limit: int = 8) -> dict[str, int]:
    found = {}
    for path in sorted(root.rglob('*.py')):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                arguments = node.args
                names = [argument.arg for argument in
                         arguments.posonlyargs + arguments.args + arguments.kwonlyargs]
                count = len([name for name in names if name not in ('self', 'cls')]) + \
                    (arguments.vararg is not None) + (arguments.kwarg is not None)
                if count >= limit:
                    found[f'{path.relative_to(root).as_posix()}:{node.name}'] = count
    return found


def test_no_new_function_takes_eight_or_more_parameters():
    found = _long_parameter_lists(ROOT)
    assert set(found) <= set(KEPT), (
        f'{sorted(set(found) - set(KEPT))} take 8 or more parameters: group those that '
        'travel together in a small frozen dataclass, or take the pipeline state')
