"""
The manual shows current output: its generated blocks and figures match what the code prints now.

``tools/generate_docs.py`` runs the commands the manual shows and rewrites the blocks between
``<!-- generated: NAME -->`` and ``<!-- end -->`` and the report figures of docs/_static; these
tests rerun the commands (without drawing the figures) and fail when a page or a figure's
recorded numbers differ: then run ``make docs-regenerate`` and commit the pages.
"""

import copy
import importlib.util
import json
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
        if not generate_docs.same_numbers(before, text):
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
    same = recorded is not None and generate_docs.same_numbers(
        json.dumps(recorded, sort_keys=True), json.dumps(now, sort_keys=True))
    assert same, (f'docs/_static/{figure} shows {recorded}, the code now gives {now}: '
                  f'{generate_docs.REGENERATE}')


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


def test_the_last_digit_of_a_decimal_may_differ_nothing_else():
    """Another CPU may round a fitted value the other way; a changed number still fails."""
    same = generate_docs.same_numbers
    text = '# Ra 0.995 Ohm, kV 59.95 .. 60.05, 0 of 30 false, stderr 0.05 to 0.12 %'
    assert same(text, text.replace('0.995', '0.996'))
    assert same(text, text.replace('0.05 to', '0.06 to'))
    assert same(text, text.replace('60.05', '60.1'))  # 1e-3 of the value
    assert not same(text, text.replace('0.995', '0.998'))
    assert not same(text, text.replace('59.95', '59.8'))
    assert not same(text, text.replace('0 of 30', '1 of 30'))  # integers: exact
    assert not same(text, text.replace('Ohm', 'ohm'))
    assert not same(text, text.replace('0.995', '9.995'))


BENCH_TEXT = """# Results

## 1. Accuracy

| motor | noise % | Ra | z rms |
|---|---|---|---|
| paper1 | 1 | 0.26 | 0.7-0.9 |
| paper2 | 1 | 0.0203 | 1.1-1.5 |
| paper2 | 3 | 0.054 | 0.9-1 |

- wall time 109 s (1.466 windows/s)
"""


def quoted(spec):
    return generate_docs.quoted_value(generate_docs._spec(spec), lambda name: BENCH_TEXT)


def test_a_quoted_number_is_read_from_its_table():
    assert quoted('bench: x.md; table: Accuracy; row: motor = paper2 & noise % = 3; '
                  'column: Ra') == '0.054'
    assert quoted('bench: x.md; table: Accuracy; row: noise % = 1; column: Ra; '
                  'value: max') == '0.26'
    assert quoted('bench: x.md; table: Accuracy; row: motor ~ paper; column: z rms; '
                  'value: range; format: .2g') == '0.7-1.1'
    assert quoted('bench: x.md; table: Accuracy; row: motor = paper1; column: z rms; '
                  'part: 2') == '0.9'
    assert quoted(r'bench: x.md; match: wall time ([\d.]+) s') == '109'
    with pytest.raises(RuntimeError, match='2 rows'):
        quoted('bench: x.md; table: Accuracy; row: noise % = 1; column: Ra')
    with pytest.raises(RuntimeError, match='no row'):
        quoted('bench: x.md; table: Accuracy; row: motor = paper3; column: Ra')


def test_a_changed_bench_table_makes_the_quoting_page_stale(monkeypatch):
    page = ('Ra within <!-- from: bench: x.md; table: Accuracy; row: noise % = 1; column: Ra; '
            'value: max -->0.26<!-- /from --> %.')
    assert generate_docs.fill_quoted(page, lambda name: BENCH_TEXT) == page
    changed = BENCH_TEXT.replace('| 0.26 |', '| 0.31 |')
    text = generate_docs.fill_quoted(page, lambda name: changed)
    assert '-->0.31<!--' in text and not generate_docs.same_numbers(page, text)


def test_every_quoted_number_names_a_committed_table():
    """Each quoted number of the manual is found, once, in a committed results file."""
    count = 0
    for path in generate_docs.quoting_pages():
        with open(path, encoding='utf-8') as stream:
            for match in generate_docs.QUOTED.finditer(stream.read()):
                spec = generate_docs._spec(match.group('spec'))
                assert generate_docs.quoted_value(spec, generate_docs.read_bench) == match.group(
                    'body'), (path, match.group('spec'))
                count += 1
    assert count >= 150  # 162 when written: a page that lost its quoting fails here


def test_an_empty_cell_keeps_the_columns_in_place():
    text = ('## T\n\n| model | criterion | RMSE |\n|---|---|---|\n| a | | **8.41** |\n'
            '| b | x | 9 |\n')
    spec = generate_docs._spec('bench: x.md; table: T; row: model = a; column: RMSE; part: 1')
    assert generate_docs.quoted_value(spec, lambda name: text) == '8.41'


def test_a_count_of_the_rows_meeting_the_conditions():
    assert quoted('bench: x.md; table: Accuracy; row: motor ~ paper2; value: count') == '2'
    assert quoted('bench: x.md; table: Accuracy; row: noise % = 3; value: count') == '1'
    with pytest.raises(RuntimeError, match='no row'):
        quoted('bench: x.md; table: Accuracy; row: motor = paper3; value: count')


def test_a_count_from_percentages_of_trials():
    text = ('## T\n\n| mode | trials | false |\n|---|---|---|\n| a | 15 | 20 % |\n'
            '| a | 15 | 0 % |\n| b | 15 | 40 % |\n')
    spec = generate_docs._spec('bench: x.md; table: T; row: mode = a; column: false; '
                               'value: sum; per: trials; format: .0f')
    assert generate_docs.quoted_value(spec, lambda name: text) == '3'


def test_a_fitted_value_rounded_the_other_way_is_not_stale_a_changed_one_is(sessions):
    """The design example's kp printed one unit off in its last digit passes, 1 % off fails."""
    page = os.path.join(ROOT, 'docs', 'control_design.md')
    before, text = generate_docs.regenerate_pages(sessions)[page]
    assert generate_docs.same_numbers(before, text)
    printed = next(line for line in text.split('\n') if line.startswith('    # speed PI  kp = '))
    kp = generate_docs.NUMBER.findall(printed)[0]
    digits = len(kp.split('.')[1])
    for shift, same in ((10.0 ** -digits, True), (0.01 * float(kp), False)):
        other = f'{float(kp) + shift:.{digits}f}'
        assert generate_docs.same_numbers(
            before, text.replace(printed, printed.replace(kp, other, 1))) is same, other
