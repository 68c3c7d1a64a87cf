"""
EMPS scored as the benchmark community scores it: position RMSE on DATA_EMPS_PULSES.

Trains on DATA_EMPS and simulates DATA_EMPS_PULSES open loop from the force ``gtau * vir``;
the score is the position RMSE in mm after the first 20 samples. The published IDIM-LS
parameters and the 4-parameter rigid-model output-error fits are computed in the same run
(:func:`studies.emps.emps_score`).

    EMPS_DATA_DIR=../shared/data/emps python bench/bench_emps_score.py [--out FILE.md]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from studies.emps import emps_score, format_score  # noqa: E402


def main() -> int:
    """Run the score and write the markdown table."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('data_dir', nargs='?')
    parser.add_argument('--out', default=os.path.join(HERE, 'emps_score_results.md'))
    args = parser.parse_args()
    load = os.getloadavg()
    start = time.perf_counter()
    score = emps_score(args.data_dir)
    seconds = time.perf_counter() - start
    pulses = score['pulses']
    text = ['# EMPS: position RMSE on the PULSES validation record', '',
            'Command: `EMPS_DATA_DIR=../shared/data/emps python bench/bench_emps_score.py` '
            f'({seconds:.0f} s; load average {load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f} at '
            'the start, 2 shared cores). Every model is trained on DATA_EMPS and simulated '
            'open loop on DATA_EMPS_PULSES from the force gtau * vir (exact simulation, '
            'stick-slip included), initial speed estimated on the first 20 samples; score = '
            'position RMSE after those 20 samples (`dcmotor_id.validate`).', '',
            format_score(score), '',
            f'The force pulses: {pulses["pulses"]} onsets of `pulses_N` (height '
            f'{pulses["pulse_height"]:g}); at each onset the recorded `vir` of the PULSES '
            'record jumps against the DATA_EMPS one by a median '
            f'{pulses["median_jump_of_vir_at_onset"]:.3f} V in one sample, i.e. the pulse is '
            'in the recorded input (a step no position loop produces within one sample), and '
            'the position loop then pulls it back (the carriage moves at most '
            f'{pulses["max_position_difference_m"] * 1e3:.3f} mm off the DATA_EMPS path).', '']
    with open(args.out, 'w', encoding='utf-8') as stream:
        stream.write('\n'.join(text))
    print('\n'.join(text))
    return 0


if __name__ == '__main__':
    sys.exit(main())
