"""
The manual shows current output: its generated blocks and figures match what the code prints now.

``tools/generate_docs.py`` runs the commands the manual shows and rewrites the blocks between
``<!-- generated: NAME -->`` and ``<!-- end -->`` and the report figures of docs/_static; these
tests rerun the commands (without drawing the figures) and fail when a page or a figure's
recorded numbers differ: then run ``make docs-regenerate`` and commit the pages.
"""

import copy
import importlib.util
import os
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_SPEC = importlib.util.spec_from_file_location('generate_docs',
                                               os.path.join(ROOT, 'tools', 'generate_docs.py'))
generate_docs = importlib.util.module_from_spec(_SPEC)
sys.modules['generate_docs'] = generate_docs  # its dataclasses look their module up
_SPEC.loader.exec_module(generate_docs)


@pytest.fixture(scope='module')
def sessions(tmp_path_factory):
    """Run the manual's commands once, as the generator runs them (no figures)."""
    return generate_docs.run_all(str(tmp_path_factory.mktemp('docs_sessions')), figures=False)


def test_every_generated_block_shows_the_current_output(sessions):
    pages = generate_docs.regenerate_pages(sessions)
    stale = {}
    for path, (before, text) in pages.items():
        if before != text:
            old, new = before.split('\n'), text.split('\n')
            first = next((n for n, pair in enumerate(zip(old, new)) if pair[0] != pair[1]),
                         min(len(old), len(new)))
            stale[os.path.relpath(path, ROOT)] = (first + 1, new[first] if first < len(new)
                                                  else '')
    assert not stale, ('the manual shows output the code no longer prints (page: first '
                       f'differing line, what it prints now): {stale}; '
                       f'{generate_docs.REGENERATE} and commit the pages')
    assert {os.path.relpath(path, ROOT) for path in pages} >= {
        'README.md', 'docs/getting_started.md', 'docs/closing_the_loop.md',
        'docs/control_design.md'}


@pytest.mark.parametrize('figure', ['report_fit.png', 'report_transients.png'])
def test_the_report_figures_record_the_current_numbers(sessions, figure):
    recorded = generate_docs.recorded_numbers(os.path.join(generate_docs.STATIC, figure))
    now = generate_docs.figure_numbers(sessions['stribeck'].json('result.json'))
    assert recorded == now, (f'docs/_static/{figure} shows {recorded}, the code now gives '
                             f'{now}: {generate_docs.REGENERATE}')


def test_a_changed_output_makes_a_page_stale(sessions):
    changed = copy.deepcopy(sessions)
    changed['stribeck'].stdout['identify'] = changed['stribeck'].stdout['identify'].replace(
        'excess_Nm = ', 'excess_Nm = 9')
    page = os.path.join(ROOT, 'docs', 'closing_the_loop.md')
    before, text = generate_docs.regenerate_pages(changed)[page]
    assert before != text and 'excess_Nm = 9' in text


def test_a_block_nobody_makes_is_refused(tmp_path, monkeypatch, sessions):
    page = tmp_path / 'page.md'
    page.write_text('<!-- generated: no-such-block -->\n<!-- end -->\n')
    monkeypatch.setattr(generate_docs, 'ROOT', str(tmp_path))
    monkeypatch.setattr(generate_docs, 'BLOCKS', {'x': ('page.md', lambda s: 'x')})
    with pytest.raises(RuntimeError, match='0 blocks named x'):
        generate_docs.regenerate_pages(sessions)
