"""The review's exceedance list by probability (issue 12 item 5): with the paper's Table 3 the
band-edge list holds false alarms; ``--min-probability`` keeps the real exceedances only."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from railgsa_ros.bag import write_run
from railgsa_ros.cli import review
from railgsa_ros.cli.main import main
from railgsa_ros.inverse.score import band_distance
from railgsa_ros.review.build import build_review
from railgsa_ros.review.exceedances import Exceedance, listed
from railgsa_ros.review.outputs import defect_rows
from railgsa_ros.review.results import ReviewOptions
from railgsa_ros.scenario import run_scenario
from railgsa_ros.uncertainty import UncertaintyConfig
from railgsa_ros.uncertainty.parameters import table3

SPEED = 30.0  # 108 km/h: AL 8 mm (lower end)
DEFECTS = 'dip@300:len=6:depth=14e-3,dip@700:len=6:depth=6e-3'
CONFIG = UncertaintyConfig(qoi='')


@pytest.fixture(scope='module')
def simulated(tmp_path_factory: pytest.TempPathFactory):
    run = run_scenario('german-high', SPEED, 1000.0 / SPEED, None, 'bmi088', 4, defects=DEFECTS)
    return write_run(tmp_path_factory.mktemp('prob') / 'run', run), run


def _truth_passes(run, e) -> bool:
    x = np.arange(0.0, run.chainage_m[-1], 0.25)
    u = band_distance(np.interp(x, run.chainage_m, run.truth_u_m), 0.25)
    near = (x >= e.start_m - 1.0) & (x <= e.end_m + 1.0)
    return bool(np.max(np.abs(u[near])) > e.limit_m)


def _command_line(*argv: str) -> ReviewOptions:
    """ReviewOptions as ``railgsa review`` builds them from ``argv`` (sensitivities off: cost)."""
    parser = argparse.ArgumentParser()
    review.register(parser.add_subparsers())
    return replace(review.build_options(parser.parse_args(['review', *argv])), config=CONFIG)


def test_min_probability_keeps_the_real_exceedances_only(simulated):
    """The review's default (--min-probability 0.5) lists every real exceedance and no false
    alarm; --min-probability 0 lists every band-edge stretch, false alarms included."""
    bag, run = simulated
    every = build_review(_command_line(str(bag), '--out', 'DIR', '--min-probability', '0'))
    kept = build_review(_command_line(str(bag), '--out', 'DIR'))
    assert kept.options.min_probability == 0.5 and kept.options.dists == table3()
    assert all(0.0 <= e.probability <= 1.0 for e in every.exceedances)
    assert {e.start_m for e in kept.exceedances} <= {e.start_m for e in every.exceedances}
    real = [e for e in every.exceedances if _truth_passes(run, e)]
    assert any(abs(e.peak_m - 303.0) < 8 for e in real)  # the 14 mm dip
    assert len(every.exceedances) > len(real)  # band-edge false alarms with Table 3
    assert all(_truth_passes(run, e) for e in kept.exceedances)  # no false alarm left
    assert {e.start_m for e in kept.exceedances} == {e.start_m for e in real}  # no miss


def test_min_probability_outside_0_1_is_refused(simulated, tmp_path: Path, capsys):
    bag, _ = simulated
    assert main(['review', str(bag), '--out', str(tmp_path / 'r'), '--min-probability',
                 '1.5']) == 2
    assert '--min-probability' in capsys.readouterr().err
    assert not (tmp_path / 'r').exists()


def _exceedance(level: str, peak_mm: float, probability: float, alert_probability: float,
                confidence: str = 'likely') -> Exceedance:
    """A stretch at 108 km/h (AL 8, IL 10 mm) with its two probabilities."""
    limit = {'AL': 8.0, 'IL': 10.0}[level]
    return Exceedance(level, confidence, 0.0, 5.0, 2.5, 0, -peak_mm * 1e-3, -14e-3, -5e-3,
                      limit * 1e-3, 108.0, probability, 8e-3, alert_probability)


def test_the_cut_keeps_what_passes_the_alert_limit():
    """Issue 22: a stretch 30 % over the alert limit, unlikely to pass the intervention limit
    its row is listed at, is kept (its central value passes AL, P(AL) = 0.9); a band-edge
    stretch unlikely to pass anything is dropped; one without a band is kept."""
    real = _exceedance('IL', 10.4, 0.3, 0.9)
    edge = _exceedance('AL', 7.0, 0.2, 0.2, 'possible')
    likely_al = _exceedance('AL', 7.5, 0.1, 0.6, 'possible')  # its P(AL) reaches the cut
    unbanded = _exceedance('AL', 7.0, float('nan'), float('nan'), 'possible')
    central = _exceedance('IL', 10.4, 0.1, 0.2)  # an odd band: the central value still counts
    kept = listed([real, edge, likely_al, unbanded, central], 0.5)
    assert kept == [real, likely_al, unbanded, central]


def test_each_defect_has_its_alert_probability(simulated):
    """Every listed stretch carries P(|u| > AL) >= P(|u| > its limit) (AL is the lower
    limit; at AL level they are the same number) and the alert limit of the speed class; the
    CSV has both columns. The 14 mm dip is listed."""
    bag, _ = simulated
    every = build_review(_command_line(str(bag), '--out', 'DIR', '--min-probability', '0'))
    assert every.exceedances
    for e in every.exceedances:
        assert e.alert_limit_m == pytest.approx(8e-3)
        assert e.alert_probability >= e.probability - 1e-12
        if e.level == 'AL':
            assert e.alert_probability == pytest.approx(e.probability, abs=1e-12)
    rows = defect_rows(every)
    assert all(r['alert_limit_mm'] == 8.0 and r['alert_probability'] is not None for r in rows)
    kept = build_review(_command_line(str(bag), '--out', 'DIR'))
    assert any(abs(e.peak_m - 303.0) < 8 for e in kept.exceedances)
    assert all(abs(e.peak_u_m) > e.alert_limit_m or e.alert_probability >= 0.5
               for e in kept.exceedances)
