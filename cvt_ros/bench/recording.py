"""Cost of recording a simulation (:class:`cvt_ros.recording.SimulationRecorder`) per message
and per control period of the node's loop: ``python -m cvt_ros.bench.recording [-n N] [--repeat R]``
(results in docs/recording.md, "Recording cost")."""

from __future__ import annotations

import os
import sys
import tempfile
import time

import numpy as np

from .. import interface as I
from ..recording.recorder import SimulationRecorder
from ..scene import load_scene
from ..solver.output import N_COLUMNS
from ..solver.simulator import Simulator

__all__ = ['benchmark', 'main']


def benchmark(n: int = 20_000, steps: int = 3000) -> dict[str, float]:
    """Cost of recording [µs per message unless named otherwise], measured in this process:

    * ``sample_us``: :meth:`SimulationRecorder.record_sample` on the caller's thread (JointState
      CDR, queue), wall time, with the writer thread running alongside;
    * ``clock_us``: :meth:`SimulationRecorder.record_clock`, likewise;
    * ``rclpy_joint_state_us``: :meth:`SimulationRecorder.write` of an rclpy JointState (the
      node's hook as it is today: rclpy serialization, exact CDR size, queue);
    * ``cpu_per_message_us``: CPU time of the whole process (caller + writer thread: MCAP
      records, chunks, file writes) per message, for joint_states + /clock at equal counts;
    * ``bytes_per_sample``: file size per recorded sample (joint_states + /clock);
    * ``step_us`` / ``step_recording_us``: one 1 ms control period of the node's loop (paper
      scene, rk4: ``Simulator.advance`` + ``sample``) without and with recording its sample,
      /clock and clutch switches — the real-time budget that matters (1000 µs at 1 kHz).
    """
    rows = np.random.default_rng(1).normal(size=(n, N_COLUMNS))
    rows[:, 0] = np.arange(n) * 1e-3
    out: dict[str, float] = {'messages': float(2 * n)}
    with tempfile.TemporaryDirectory() as tmp:
        target = os.path.join(tmp, 'bench.mcap')
        cpu0 = time.process_time()
        rec = SimulationRecorder(target, overwrite=True, on_error=None, source='benchmark')
        t = time.perf_counter()
        for row in rows:
            rec.record_sample(row)
        out['sample_us'] = (time.perf_counter() - t) / n * 1e6
        t = time.perf_counter()
        for row in rows:
            rec.record_clock(row[0])
        out['clock_us'] = (time.perf_counter() - t) / n * 1e6
        rec.close()
        out['cpu_per_message_us'] = (time.process_time() - cpu0) / (2 * n) * 1e6
        out['bytes_per_sample'] = os.path.getsize(target) / n

        msg = I.joint_state_from_row(rows[0])
        rec = SimulationRecorder(target, overwrite=True, on_error=None, source='benchmark')
        topic = rec.topics['joint_states']
        t = time.perf_counter()
        for i in range(n):
            I.set_stamp(msg.header.stamp, i * 1_000_000)
            rec.write(topic, msg, i * 1_000_000)
        out['rclpy_joint_state_us'] = (time.perf_counter() - t) / n * 1e6
        rec.close()

        values = dict(load_scene('paper'), **{'solver.method': 'rk4'})
        for recording in (False, True):
            sim = Simulator(values)
            sim.advance(0.5)  # past the start-up transient
            rec = SimulationRecorder(target, overwrite=True, on_error=None,
                                     source='benchmark') if recording else None
            t = time.perf_counter()
            for _ in range(steps):
                switches = sim.advance(1e-3)
                row = sim.sample()
                if rec is not None:
                    for sw in switches:
                        rec.record_switch(sw)
                    rec.record_sample(row)
                    rec.record_clock(row[0])
            elapsed = (time.perf_counter() - t) / steps * 1e6
            if rec is not None:
                rec.close()
            out['step_recording_us' if recording else 'step_us'] = elapsed
    return out


def main(argv: list[str] | None = None) -> int:
    import argparse

    parser = argparse.ArgumentParser(
        prog='python -m cvt_ros.bench.recording',
        description='Measure the recording cost per message (see docs/recording.md).')
    parser.add_argument('-n', type=int, default=20_000, help='samples per measurement')
    parser.add_argument('--repeat', type=int, default=3,
                        help='runs; the median and the worst are reported')
    args = parser.parse_args(argv)
    runs = [benchmark(args.n) for _ in range(max(1, args.repeat))]
    print(f"{'quantity':22s} {'median':>10s} {'worst':>10s}   ({len(runs)} runs, {args.n} samples)")
    for key in runs[0]:
        values = sorted(r[key] for r in runs)
        print(f'{key:22s} {values[len(values) // 2]:10.2f} {values[-1]:10.2f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
