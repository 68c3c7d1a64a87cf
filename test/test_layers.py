"""The tree is the architecture: imports run only downward, and no module imports in a cycle."""

import ast
import pathlib

import dcmotor_id
import dcmotor_id.identification

PACKAGE = pathlib.Path(dcmotor_id.__file__).parent


def floor_of(package: str) -> int:
    """Return the floor (0 = ground) of a subpackage of dcmotor_id."""
    for floor, names in enumerate(dcmotor_id.LAYERS):
        if package in names:
            return floor
    raise AssertionError(f'dcmotor_id.{package} is on no floor of dcmotor_id.LAYERS')


def module_name(path: pathlib.Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix('').parts
    return '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)


def is_module(dotted: str) -> bool:
    path = PACKAGE.parent.joinpath(*dotted.split('.'))
    return path.with_suffix('.py').is_file() or (path / '__init__.py').is_file()


def imports(path: pathlib.Path, top_level_only: bool = False):
    """Yield (line, module) of every dcmotor_id import of a file (lazy ones too)."""
    tree = ast.parse(path.read_text())
    nodes = tree.body if top_level_only else ast.walk(tree)
    for node in nodes:
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if node.module.startswith('dcmotor_id.'):
                for alias in node.names:  # ``from package import module`` names the module
                    dotted = f'{node.module}.{alias.name}'
                    yield node.lineno, dotted if is_module(dotted) else node.module
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith('dcmotor_id.'):
                    yield node.lineno, alias.name


def sources():
    return sorted(PACKAGE.rglob('*.py'))


def test_every_subpackage_has_a_floor():
    packages = {path.name for path in PACKAGE.iterdir()
                if path.is_dir() and (path / '__init__.py').exists()}
    assert packages == {name for names in dcmotor_id.LAYERS for name in names}
    assert not [path.name for path in PACKAGE.glob('*.py') if path.name != '__init__.py'], \
        'modules belong in a subpackage (a floor), not at the package root'


def test_imports_run_only_downward():
    upward = []
    for path in sources():
        relative = path.relative_to(PACKAGE).parts
        if len(relative) < 2:
            continue
        mine = floor_of(relative[0])
        for line, module in imports(path):
            theirs = floor_of(module.split('.')[1])
            if theirs > mine:
                upward.append(f'{path.relative_to(PACKAGE.parent)}:{line} imports {module}')
    assert not upward, 'imports that run up a floor:\n' + '\n'.join(upward)


def test_no_import_cycles_between_modules():
    graph = {}
    for path in sources():
        graph[module_name(path)] = {module for _, module in imports(path, top_level_only=True)}
    state: dict = {}

    def visit(node, trail):
        state[node] = 'open'
        for target in sorted(graph.get(node, ())):
            if target not in graph:
                continue
            if state.get(target) == 'open':
                cycle = trail[trail.index(target):] + [target] if target in trail else [target]
                raise AssertionError('import cycle: ' + ' -> '.join(cycle))
            if target not in state:
                visit(target, trail + [target])
        state[node] = 'done'

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])


def test_layer_check_catches_an_upward_import(tmp_path):
    """The check itself: an import from the ground floor into the nodes is found."""
    fake = tmp_path / 'model.py'
    fake.write_text('from dcmotor_id.nodes.identifier import main\n')
    found = [(line, module) for line, module in imports(fake)]
    assert found == [(1, 'dcmotor_id.nodes.identifier')]
    assert floor_of('nodes') > floor_of('core')


def test_the_nodes_do_not_run_the_command_line():
    """The command line is an entry point, not a library: nodes call the layers below it."""
    found = [f'{path.relative_to(PACKAGE.parent)}:{line} imports {module}'
             for path in sorted((PACKAGE / 'nodes').rglob('*.py'))
             for line, module in imports(path) if module.startswith('dcmotor_id.cli')]
    assert not found, 'nodes that import the command line:\n' + '\n'.join(found)


IDENTIFICATION = PACKAGE / 'identification'


def inner_floor(name: str) -> int:
    """Return the floor of a module or subpackage of dcmotor_id.identification."""
    for floor, names in enumerate(dcmotor_id.identification.LAYERS):
        if name in names:
            return floor
    raise AssertionError(f'dcmotor_id.identification.{name} is on no floor of '
                         'dcmotor_id.identification.LAYERS')


def test_everything_inside_identification_has_a_floor():
    inside = {path.stem if path.is_file() else path.name for path in IDENTIFICATION.iterdir()
              if (path.suffix == '.py' and path.name != '__init__.py')
              or (path.is_dir() and (path / '__init__.py').exists())}
    assert inside == {name for names in dcmotor_id.identification.LAYERS for name in names}


def test_imports_inside_identification_run_only_downward():
    """Lazy imports and those under TYPE_CHECKING count too: none may run up a floor."""
    upward = []
    for path in sorted(IDENTIFICATION.rglob('*.py')):
        relative = path.relative_to(IDENTIFICATION).parts
        if relative == ('__init__.py',):
            continue
        mine = inner_floor(relative[0].removesuffix('.py'))
        for line, module in imports(path):
            parts = module.split('.')
            if parts[:2] != ['dcmotor_id', 'identification'] or len(parts) < 3:
                continue
            if inner_floor(parts[2]) > mine:
                upward.append(f'{path.relative_to(PACKAGE.parent)}:{line} imports {module}')
    assert not upward, 'imports inside identification that run up a floor:\n' + \
        '\n'.join(upward)


def test_the_inner_layer_check_catches_an_upward_import(tmp_path):
    """The check itself: an estimator importing a check is found, on a higher floor."""
    fake = tmp_path / 'refined.py'
    fake.write_text('def f():\n    from dcmotor_id.identification.checks.start import bic\n')
    found = [module for _, module in imports(fake)]
    assert found == ['dcmotor_id.identification.checks.start']
    assert inner_floor('checks') > inner_floor('estimators')
