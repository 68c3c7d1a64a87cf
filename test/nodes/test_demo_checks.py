"""The demo says what it fitted and refuses less data than it announced (no ROS graph)."""

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from dcmotor_id.nodes.demo import _enough, _streams


def test_the_demo_prints_the_data_fitted_and_refuses_less_than_announced(capsys):
    answer = 'refined: Ra=1.6 Ohm (current 1 %, speed 1 %; {} samples in {} window(s))'
    assert _enough(answer.format(12000, 1), 12.0, 1000.0)
    out = capsys.readouterr().out
    assert 'fitted 12000 samples (12.000 s at 1000 Hz) in 1 window(s); announced 12 s' in out
    # the run: 12 s announced, one 0.7 s window fitted
    assert not _enough(answer.format(700, 1), 12.0, 1000.0)
    out = capsys.readouterr().out
    assert 'fitted 700 samples (0.700 s' in out and 'refused' in out
    assert not _enough('refined: Ra=1.6 Ohm', 12.0, 1000.0)


def test_the_demo_reads_samples_and_whole_windows_from_the_streams_status():
    def array(name, emitted, windows):
        return DiagnosticArray(status=[DiagnosticStatus(name=name, values=[
            KeyValue(key='emitted', value=str(emitted)),
            KeyValue(key='windows_in_memory', value=str(windows))])])
    assert _streams([]) == (0, 0)
    assert _streams([array('identifier: streams', 500, 0), array('identifier: identify', 9, 7),
                     array('identifier: streams', 12100, 1)]) == (12100, 1)
