"""A scenario run streams (issue 34: a day-long run allocated its whole time grid up front): the
harness's buffers stay one block whatever the length, the memory a thinned run holds does not grow
with its duration, and the step metrics made block by block are the whole trace's."""
import math
import textwrap
import tracemalloc

import numpy as np
import pytest

from cvt_ros.recording.reader import summary
from cvt_ros.scenario import harness, load_scenario, run_scenario, stream
from cvt_ros.scenario.plot import plot_run
from cvt_ros.scenario.recording import write_mcap

SCENARIO = """\
    scene: {scene}
    duration: {duration}
    setpoint: {{initial: 55.0, changes: [{{at: 0.4, step: 60.0}},
                                         {{at: 1.1, ramp: {{to: 50.0, duration: 0.3}}}}]}}
    load: {{changes: [{{at: 0.75, step: 9.0}}]}}
    """


def scenario(folder, duration, scene='conveyor'):
    path = folder / f"{scene}_{duration:g}.yaml"
    path.write_text(textwrap.dedent(SCENARIO.format(duration=duration, scene=scene)))
    return load_scenario(path)


def same(a, b):
    """Equal to rounding (the stream sums crank travel and IAE block by block)."""
    if isinstance(a, float) and math.isnan(a):
        return isinstance(b, float) and math.isnan(b)
    if isinstance(a, float):
        return b == pytest.approx(a, rel=1e-12, abs=1e-15)
    return a == b


@pytest.mark.parametrize('block, scene', [(64, 'conveyor'), (997, 'conveyor'),
                                          (64, 'conveyor_4path')])
def test_the_streamed_step_metrics_are_the_whole_traces(tmp_path, monkeypatch, block, scene):
    """Blocks of 64 periods (cycles and step windows cross block ends) and of 997, one path and
    four (each clutch's switches; the metrics count "any engaged"): every step's figures and the
    run-level ones, from the start and from a time named before the run, as stepinfo gives them
    on the whole trace the run kept; the recording made as the run went is write_mcap's."""
    monkeypatch.setattr(stream, 'BLOCK', block)
    run = run_scenario(scenario(tmp_path, 2.0, scene), metrics_since=0.5,
                       mcap=tmp_path / 'streamed.mcap')
    assert run.recording_error is None
    assert write_mcap(run, tmp_path / 'whole.mcap') == (run.recording_count, None)
    streamed, whole = (summary(tmp_path / f).topics for f in ('streamed.mcap', 'whole.mcap'))
    assert {k: v.message_count for k, v in streamed.items()} == \
        {k: v.message_count for k, v in whole.items()}
    assert run.whole_trace and run.summary.error is None
    exact, streamed = run.steps, run.summary.steps
    assert [s['kind'] for s in exact] == ['start', 'setpoint', 'load', 'setpoint']
    assert len(streamed) == len(exact)
    for e, s in zip(exact, streamed, strict=True):
        assert e.keys() == s.keys()
        bad = {k: (e[k], s[k]) for k in e if not same(e[k], s[k])}
        assert not bad, (e['t'], bad)
    for since in (None, 0.5):
        e, s = run.metrics_since(since), run.summary.metrics_since(since)
        bad = {k: (e[k], s[k]) for k in e if not same(e[k], s[k])}
        assert not bad, (since, bad)
    assert sum(math.isfinite(v) for v in run.metrics.values()) >= 6


def test_a_long_run_holds_one_block_and_a_bounded_trace(tmp_path, monkeypatch):
    """Runs of 3 and 30 s with blocks (and schedule chunks) of 256 periods and a kept trace of
    at most 1000 samples: the harness's buffers are one block, the kept trace thinned to the
    bound, and the peak of what Python and numpy allocate does not grow with the duration (the
    whole grid did: 10x; what grows is the open step window's cycles, 24 B a crank turn)."""
    monkeypatch.setattr(stream, 'BLOCK', 256)
    monkeypatch.setattr(stream, 'KEEP_PERIODS', 1000)
    monkeypatch.setattr(harness, 'SCHEDULE_CHUNK', 256)
    buffers = []
    start = stream.RunStream.start
    monkeypatch.setattr(stream.RunStream, 'start',
                        lambda self, row: buffers.append(start(self, row)) or buffers[-1])
    peaks = {}
    for duration in (3.0, 30.0):
        sc = scenario(tmp_path, duration)
        run_scenario(sc)   # (the first run of a size warms caches)
        tracemalloc.start()
        run = run_scenario(sc)
        peaks[duration] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        rows, commands = buffers[-1]
        assert rows.shape[0] == commands.shape[0] == 256
        assert run.ok and not run.whole_trace and run.sample_stride == -(-(sc.periods + 1) // 1000)
        assert len(run.samples) <= 1000 and run.duration == pytest.approx(duration)
        assert run.switches == [] and run.switch_count > 40 * duration
        assert sum(math.isfinite(v) for v in run.metrics.values()) >= 6
        with pytest.raises(ValueError, match='keep_samples=True'):
            run.trace()
    plot_run(run, tmp_path / 'long.png')   # (from the outline the stream made)
    assert (tmp_path / 'long.png').read_bytes()[:4] == b'\x89PNG'
    # kept whole, 30 s is 30 000 rows of 22 floats (5.3 MB): 5.8 times 3 s's peak; streamed
    # 1.5 times (the plot's outline goes from 3001 raw points to its 4000 columns)
    assert peaks[30.0] < 2.0 * peaks[3.0], peaks


def test_a_thinned_run_names_its_metrics_window_before_the_run(tmp_path, monkeypatch):
    monkeypatch.setattr(stream, 'KEEP_PERIODS', 500)
    run = run_scenario(scenario(tmp_path, 2.0), metrics_since=0.5)
    assert not run.whole_trace
    assert math.isfinite(run.metrics_since(0.5)['iae'])
    with pytest.raises(ValueError, match='metrics_since=0.25'):
        run.metrics_since(0.25)


def test_the_plot_outline_keeps_its_columns(tmp_path):
    """A signal with more samples than 2·points is kept as each column's min and max: a spike
    of one sample stays in the outline."""
    outline = stream.Outline(10.0, 100_000, points=100)
    t = np.linspace(0.0, 10.0, 100_001)
    y = np.sin(t)
    y[54_321] = 7.0
    for k in range(0, len(t), 4096):
        outline.add('y', t[k:k + 4096], y[k:k + 4096])
    tt, yy = outline.get('y')
    assert len(tt) == len(yy) == 200 and outline.top('y') == 7.0
    assert np.min(yy) == pytest.approx(-1.0, abs=1e-3)
