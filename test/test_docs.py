"""The manual: docs/ builds with Sphinx without a warning, and what it names exists."""

import importlib
import os
import re
import shutil
import subprocess
import sys

import pytest

import dcmotor_id

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOCS = os.path.join(ROOT, 'docs')
# The README is the short entry point; the manual is docs/ (issue 18: about 10 KB at most).
README_MAX_BYTES = 10 * 1024
# Paths of the repository named in backquotes in the README and the manual.
NAMED_PATH = re.compile(r'`((?:dcmotor_id|test|bench|config|launch|studies)/[\w./]*[\w/])`')
# Dotted names of the package in backquotes (a module, or a name in a module).
NAMED_OBJECT = re.compile(r'`(dcmotor_id(?:\.\w+)+)[`(]')


def sphinx_build(source, out, *extra):
    """Run ``sphinx-build -W`` (warnings are errors) as ``make docs`` does; return the result."""
    command = [sys.executable, '-m', 'sphinx', '-b', 'html', '-W', '--keep-going', '-q',
               *extra, source, out]
    return subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_docs_build_without_warnings(tmp_path):
    result = sphinx_build(DOCS, str(tmp_path / 'html'), '-d', str(tmp_path / 'doctrees'))
    assert result.returncode == 0, 'the manual has warnings:\n' + result.stderr
    for page in ('index', 'getting_started', 'cli', 'formats', 'trust', 'nodes', 'online',
                 'closing_the_loop', 'control_design', 'experiment', 'fleet', 'architecture',
                 'benchmarks/index', 'benchmarks/speed_results', 'api/index'):
        assert (tmp_path / 'html' / f'{page}.html').is_file(), page
    api = (tmp_path / 'html' / 'api' / 'identification.html').read_text(encoding='utf-8')
    assert 'id="dcmotor_id.identification.identify.identify"' in api
    # Every public name of the package links to its documentation in the module of its layer.
    package = (tmp_path / 'html' / 'api' / 'package.html').read_text(encoding='utf-8')
    table = package[package.index('Public names'):]
    table = table[:table.index('</table>')]
    linked = set(re.findall(r'<a class="reference internal" href="[^"]*#dcmotor_id[.\w]*\.(\w+)"',
                            table))
    assert set(dcmotor_id.__all__) <= linked, set(dcmotor_id.__all__) - linked


@pytest.mark.slow
def test_docs_build_fails_on_a_warning(tmp_path):
    # The same configuration on a page with a broken reference: -W must turn it into a failure.
    source = tmp_path / 'src'
    source.mkdir()
    shutil.copy(os.path.join(DOCS, 'conf.py'), source / 'conf.py')
    (source / '_static').mkdir()
    (source / 'index.md').write_text('# Broken\n\nSee [a page](no_such_page.md).\n')
    env = dict(os.environ, DCMOTOR_ID_DOCS_NO_API='1')
    command = [sys.executable, '-m', 'sphinx', '-b', 'html', '-W', '-q', str(source),
               str(tmp_path / 'html')]
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=600,
                            env=env)
    assert result.returncode != 0
    assert 'no_such_page' in result.stderr


def test_readme_is_short():
    size = os.path.getsize(os.path.join(ROOT, 'README.md'))
    assert size <= README_MAX_BYTES, f'README.md is {size} bytes: move the detail into docs/'


def manual_texts():
    """Yield (path relative to the repository, text) of the README and every page."""
    paths = [os.path.join(ROOT, 'README.md')]
    for folder, _, files in os.walk(DOCS):
        if '_build' not in folder:
            paths += [os.path.join(folder, name) for name in files
                      if name.endswith(('.md', '.rst'))]
    for path in sorted(paths):
        with open(path, encoding='utf-8') as stream:
            yield os.path.relpath(path, ROOT), stream.read()


def resolves(dotted):
    """Whether ``dotted`` is a module of the package or a name in one."""
    parts = dotted.split('.')
    for split in range(len(parts), 0, -1):
        try:
            target = importlib.import_module('.'.join(parts[:split]))
        except ImportError:
            continue
        for attribute in parts[split:]:
            if not hasattr(target, attribute):
                return False
            target = getattr(target, attribute)
        return True
    return False


def test_paths_named_in_the_manual_exist():
    missing = []
    for path, text in manual_texts():
        for name in NAMED_PATH.findall(text):
            if not os.path.exists(os.path.join(ROOT, name)):
                missing.append(f'{path}: {name}')
    assert not missing, 'paths named in the manual that do not exist:\n' + '\n'.join(missing)


def test_names_of_the_package_in_the_manual_exist():
    missing = [f'{path}: {name}' for path, text in manual_texts()
               for name in NAMED_OBJECT.findall(text) if not resolves(name)]
    assert not missing, 'names in the manual that the package lacks:\n' + '\n'.join(missing)
