"""``railgsa review`` on simulated bags with known defects: exceedances at the right chainage and
level, SD per 200 m against the truth's, scores, the same band as the uncertainty core, the
injected faults in the input health, and bad input (exit 2, nothing written)."""

from __future__ import annotations

from dataclasses import replace
from html import escape
from pathlib import Path
import re

import numpy as np
import pytest

from railgsa_ros.bag import read_imu, write_run
from railgsa_ros.cli.main import main
from railgsa_ros.inverse.score import band_distance
from railgsa_ros.review.build import build_review, write_review
from railgsa_ros.review.outputs import summary
from railgsa_ros.review.results import ReviewOptions
from railgsa_ros.scenario import run_scenario
from railgsa_ros.standards.sampling import GridBuilder
from railgsa_ros.track import save_csv
from railgsa_ros.uncertainty import UncertaintyConfig, offline_bands
from railgsa_ros.uncertainty.parameters import table3

MM = 1e-3
SPEED = 20.0  # m/s = 72 km/h: class v <= 80 km/h, lower end AL 12, IL 17, IAL 28 mm
DEFECTS = 'dip@200:len=6:depth=0.02,dip@400:len=6:depth=0.03,dip@600:len=8:depth=0.05'
LIMITS_MM = (12.0, 17.0, 28.0)  # EN 13848-5 [M] as tabulated in rail_domain.md, written out
CHEAP = UncertaintyConfig(rule='pem3', order=1, germ_samples=256, n_mc=1000,
                          window_length=10.0)


@pytest.fixture(scope='module')
def simulated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    """A 40 s, 800 m ADXL355 bag over German-low track with three dips of known level."""
    run = run_scenario('german-low', SPEED, 40.0, 1000.0, 'adxl355', 1, defects=DEFECTS)
    assert np.max(np.abs(run.accel[:, 2])) < 0.95 * 2 * 9.80665  # no clipping in the sensor
    return write_run(tmp_path_factory.mktemp('review') / 'run', run), run


@pytest.fixture(scope='module')
def review(simulated: tuple[Path, object]):
    bag, _ = simulated
    return build_review(ReviewOptions(bag, CHEAP, dists=table3(), truth=bag))


def truth_band(run: object) -> tuple[np.ndarray, np.ndarray]:
    """The truth filtered to D1 on a 0.25 m grid of the simulation's chainage."""
    x = np.arange(0.0, run.chainage_m[-1], 0.25)
    return x, band_distance(np.interp(x, run.chainage_m, run.truth_u_m), 0.25)


def test_every_truth_exceedance_is_found_at_its_chainage_and_level(simulated, review) -> None:
    _, run = simulated
    x, u = truth_band(run)
    beyond = np.abs(u) > LIMITS_MM[0] * MM
    centres = np.array([203.0, 403.0, 604.0])
    assert np.all(np.min(np.abs(x[beyond][:, None] - centres), axis=1) < 8)  # only at the dips
    central = [e for e in review.exceedances if e.confidence != 'possible']
    for centre in centres:
        near = np.abs(x - centre) < 8
        k = np.argmax(np.abs(u[near]))
        level = int(np.sum(np.abs(u[near][k]) > np.array(LIMITS_MM) * MM))
        hits = [e for e in central if abs(e.peak_m - x[near][k]) < 1.0]
        assert len(hits) == 1, (centre, hits)
        assert hits[0].level == ('AL', 'IL', 'IAL')[level - 1]
        assert hits[0].peak_u_m == pytest.approx(u[near][k], abs=1 * MM)
    for e in central:  # no false alarm away from the dips
        assert np.min(np.abs(e.peak_m - centres)) < 8


def test_sd_per_200_m_matches_the_truth(simulated, review) -> None:
    _, run = simulated
    x, u = truth_band(run)
    sections = review.sections
    assert sections.start_m.tolist() == [0, 200, 400, 600]
    truth_sd = np.array([np.std(u[(x >= s) & (x < s + 200)]) for s in sections.start_m])
    # the first and last sections hold the INVALID warm-up and tail (about 50 m each)
    assert np.all(sections.coverage[1:3] > 0.95) and np.all(sections.coverage[[0, 3]] > 0.6)
    assert sections.sd_m[1:3] == pytest.approx(truth_sd[1:3], abs=0.1 * MM)
    assert np.all(np.isfinite(sections.sd_m))
    assert review.truth_sections.sd_m[1:3] == pytest.approx(truth_sd[1:3], abs=0.05 * MM)
    assert sections.speed_mps == pytest.approx(np.full(4, SPEED), rel=1e-3)


def test_scores_meet_the_simulation_targets(review) -> None:
    score = review.comparison.score
    assert score.rmse < 0.3 * MM and score.correlation > 0.9 and score.peak_error < 1 * MM
    assert review.comparison.defect_m == pytest.approx(604.0, abs=1.0)


def test_the_band_is_the_uncertainty_core_band(simulated, review) -> None:
    bag, _ = simulated
    stream = read_imu(bag)
    cfg = review.config
    band = offline_bands(stream.stamps_ns, stream.accel, (stream.odom_stamps_ns, stream.speed_mps),
                         stream.frame_ids, stream.covariance, cfg, dists=table3())
    ok = band.quality != 2  # the review grids the samples that are not INVALID
    whole = GridBuilder()  # the whole band at once on the review's grid
    whole.push(band.chainage_m[ok], band.mean_m[ok], np.zeros(ok.sum()), band.lower_m[ok],
               band.upper_m[ok])
    expected, grid = whole.grid(), review.run.grid
    assert np.array_equal(expected.x_m, grid.x_m)
    for name in ('lower_m', 'upper_m'):  # float32 on the grid: 6e-8 relative
        np.testing.assert_allclose(getattr(grid, name), getattr(expected, name),
                                   rtol=1e-6, atol=1e-9 * MM)
    assert np.all(grid.lower_m <= grid.upper_m)
    assert len(review.run) == len(band)
    # windows of 10 s: four along 40 s, each QoI, every index in [0, 1]
    run = review.run
    assert [w.qoi for w in run.windows] == ['peak', 'rms'] * 4
    assert all(np.all((w.sobol_first >= -1e-12) & (w.sobol_first <= w.sobol_total + 1e-12))
               for w in run.windows)
    worst = review.worst
    assert worst.chainage_m == pytest.approx(604.0, abs=1.0)
    k = int(np.nanargmax(np.abs(band.mean_m)))
    assert worst.stamp_ns == band.stamps_ns[k]
    assert float(worst.result.mean) == pytest.approx(band.mean_m[k] / MM, rel=1e-9)


def test_the_kept_band_equals_the_band_at_every_sample(simulated, review,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """The review computes the quantiles only where it keeps them (review.band): its grid and
    exceedances (with their band at the peak) equal those of the band computed at every sample
    (to 1e-12: the PCE coefficients' einsum rounds a sample's sums by the chunk it is in, in the
    last bit); its widest band is the widest of the samples around the grid's cells."""
    from railgsa_ros.offline import Source
    from railgsa_ros.review import band as kept
    from railgsa_ros.review.stream import run_stream
    from railgsa_ros.standards.en13848 import Limits, en13848_table

    def everywhere(self, chainage_m, u_m, speed_mps, mean_m, bank_u_m, sensor_std_m):
        lower, _, upper = kept.band_statistics(self.design, self.quantiles, bank_u_m,
                                               sensor_std_m)
        return lower, upper

    monkeypatch.setattr(kept.KeptBand, 'take', everywhere)
    bag, _ = simulated
    full, _ = run_stream(Source(bag), CHEAP, review.options.vehicle, table3(),
                         Limits(en13848_table(), 'd1'))
    run = review.run
    assert np.array_equal(run.grid.u_m, full.grid.u_m, equal_nan=True)
    for name in ('lower_m', 'upper_m'):
        np.testing.assert_allclose(getattr(run.grid, name), getattr(full.grid, name),
                                   rtol=1e-12, atol=0)
    assert run.exceedances and len(run.exceedances) == len(full.exceedances)
    for mine, theirs in zip(run.exceedances, full.exceedances, strict=True):
        band = ('lower_m', 'upper_m')
        np.testing.assert_allclose([getattr(mine, f) for f in band],
                                   [getattr(theirs, f) for f in band], rtol=1e-12, atol=0)
        assert replace(mine, lower_m=0, upper_m=0, probability=0) == \
            replace(theirs, lower_m=0, upper_m=0, probability=0)
        np.testing.assert_array_equal(mine.probability, theirs.probability)
    assert run.widest.chainage_m == pytest.approx(full.widest.chainage_m, abs=0.25)
    assert full.widest.value_m * (1 - 1e-3) <= run.widest.value_m <= full.widest.value_m
    assert run.worst.stamp_ns == full.worst.stamp_ns


def test_report_lists_the_findings_and_links_existing_figures(review, tmp_path: Path) -> None:
    report = write_review(review, tmp_path / 'out')
    html = report.read_text(encoding='utf-8')
    images = re.findall(r'<img src="([^"]+)"', html)
    assert set(images) == {'overview.png', 'closeups.png', 'sections.png', 'health.png',
                           'sensitivity.png', 'histogram.png', 'truth.png'}
    for name in images:
        assert (report.parent / name).read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert sorted(p.name for p in report.parent.iterdir()) == sorted(
        [*images, 'report.html', 'defects.csv', 'review.geojson', 'sections.csv'])
    counts = {level: sum(e.level == level for e in review.exceedances)
              for level in ('IAL', 'IL', 'AL')}
    assert all(counts.values())  # the three dips: one of each level at least
    for level, count in counts.items():
        assert re.search(f'<span class={level}>{level}</span> {count} \\(', html)
    # the table and the basis of every class are named (no --line-speed: the measuring speed)
    assert '[M]' in html and '<b>EN 13848-5, lower end of the AL/IL ranges</b>' in html
    assert '<b>class by measuring speed (no --line-speed given)</b>' in html
    assert not list(tmp_path.glob('.out*'))  # no temporary left behind
    # the input policy's findings: the mounting tilt of the upright sensor (report and --json)
    mounting = summary(review, report)['findings']['mounting']
    assert mounting['level'] == 'OK' and 'tilted 0.' in mounting['message']
    assert escape(mounting['message']) in html


def test_injected_faults_appear_in_the_input_health(tmp_path: Path) -> None:
    run = run_scenario('german-low', SPEED, 12.0, 1000.0, 'ideal', 2)
    accel = run.accel.copy()
    accel[[1000, 2000, 2001, 5000, 9000], 2] = np.nan
    stamps = run.stamps_ns.copy()
    stamps[7001] = stamps[7000]  # a repeated stamp (bags keep log-time order: no swap)
    drop = np.r_[3000:4500]  # 1.5 s without samples
    keep = np.setdiff1d(np.arange(stamps.size), drop)
    faulty = replace(run, stamps_ns=stamps[keep], accel=accel[keep], t_true_s=run.t_true_s[keep],
                     speed_mps=run.speed_mps[keep], chainage_m=run.chainage_m[keep],
                     truth_u_m=run.truth_u_m[keep])
    bag = write_run(tmp_path / 'faulty', faulty)
    review = build_review(ReviewOptions(bag))
    counters, imu = review.health.counters, review.health.imu
    assert review.health.rejected == {'nan': 5, 'wrong_frame': 0, 'saturated': 0, 'stuck': 0,
                                      'out_of_order': 0, 'duplicate': 1}
    assert counters['gap'] == 1 and counters['reset'] == 1  # 1.5 s > max_bridge_s 1.2 s
    assert imu.gaps == 1 and imu.longest_gap_s == pytest.approx(1.501, abs=1e-6)
    assert imu.backwards == 1 and imu.count == 12000 - 1500
    assert review.run.design is None and review.worst is None


def test_cli_writes_the_report_and_draws_progress_only_when_asked(simulated, tmp_path: Path,
                                                                   capsys) -> None:
    bag, run = simulated
    truth = tmp_path / 'truth.csv'
    save_csv(truth, run.chainage_m, run.truth_u_m)
    out = tmp_path / 'report'
    assert main(['review', str(bag), '--out', str(out), '--no-uncertainty', '--truth',
                 str(truth), '--limit-end', 'upper']) == 0
    stdout, stderr = capsys.readouterr()
    assert str(out / 'report.html') in stdout and 'x real time' in stdout
    assert stderr == ''
    html = (out / 'report.html').read_text(encoding='utf-8')
    assert '<b>EN 13848-5, upper end of the AL/IL ranges</b>' in html
    assert 'histogram.png' not in html and 'truth.png' in html
    assert main(['review', str(bag), '--out', str(out), '--no-uncertainty']) == 2
    assert 'already exists' in capsys.readouterr().err
    assert main(['review', str(bag), '--out', str(out), '--no-uncertainty', '--overwrite',
                 '--progress']) == 0
    assert '\rprocessing [' in capsys.readouterr().err


def _one_second(tmp_path: Path, name: str, keys: tuple[str, ...], nan: bool = False) -> Path:
    """A 1 s bag of the topics ``keys``, every acceleration NaN when ``nan``."""
    run = run_scenario('german-low', SPEED, 1.0, 1000.0, 'ideal', 3)
    if nan:
        run = replace(run, accel=np.full_like(run.accel, np.nan))
    return _bag_with(tmp_path / name, run, keys)


def _write(path: Path, text: str) -> Path:
    path.write_text(text, encoding='utf-8')
    return path


# case -> (error message, builder (tmp_path, simulated bag) -> (the file to name, extra args))
BAD_INPUT = {
    'missing bag': ('no such bag', lambda tmp, bag: (tmp / 'absent', [])),
    'corrupt bag': ('unfinished (no MCAP footer', lambda tmp, bag: (
        _write(tmp / 'corrupt.mcap', '\x89MCAP0\r\n' + 'garbage' * 100), [])),
    'empty bag': ('has no messages', lambda tmp, bag: (_bag_with(
        tmp / 'empty', run_scenario('german-low', SPEED, 1.0, 1000.0, 'ideal', 3), ('imu',), 0),
        [])),
    'all samples NaN': ('no usable IMU sample', lambda tmp, bag: (
        _one_second(tmp, 'nan', ('imu', 'odom'), nan=True), [])),
    'no imu topic': ('no topic /imu/other', lambda tmp, bag: (bag, ['--imu-topic', '/imu/other'])),
    'bad truth csv': ('expected the header x_m,u_m', lambda tmp, bag: (
        _write(tmp / 'truth.csv', 'x,u\n0,0\n1,0\n'), ['--truth'])),
    'truth without topic': ('no topic /track/irregularity_truth', lambda tmp, bag: (
        _one_second(tmp, 'no_truth', ('imu', 'odom')), ['--truth'])),
    'bad params': ('method', lambda tmp, bag: (_write(
        tmp / 'params.yaml', 'uncertainty_node:\n  ros__parameters:\n    method: magic\n'),
        ['--params'])),
}


@pytest.mark.parametrize('case', list(BAD_INPUT))
def test_bad_input_exits_2_naming_the_file_and_writes_nothing(simulated, tmp_path: Path,
                                                              capsys, case: str) -> None:
    bag, _ = simulated
    message, build = BAD_INPUT[case]
    named, extra = build(tmp_path, bag)
    is_bag = not extra or extra[0] == '--imu-topic'
    args = ['review', str(named if is_bag else bag), '--out', str(tmp_path / 'out'),
            '--no-uncertainty', *extra, *([] if is_bag else [str(named)])]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith('error: ') and err.count('\n') == 1
    assert str(named) in err and message in err
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(('out', '.out'))]


def _bag_with(path: Path, run: object, keys: tuple[str, ...], count: int | None = None) -> Path:
    """A bag with only the topics ``keys`` ('imu', 'odom', 'truth') of a run, and only its first
    ``count`` IMU samples (None: all)."""
    from railgsa_ros.bag import BagWriter, RunEncoder

    encoder = RunEncoder(run)
    with BagWriter(path, 'mcap') as writer:
        topics = encoder.topics()
        for key in keys:
            writer.add_topic(*topics[key])
        batches = encoder.encode(0, count)
        writer.write_batches({topics[k][0]: batches[k] for k in keys})
    return path


def test_without_odometry_the_speed_is_unknown_and_refused(tmp_path: Path) -> None:
    """No silent fallback speed (issue 11): without odometry the review refuses with one line;
    a fixed speed must be asked for (run_stream's speed_mps)."""
    from railgsa_ros.errors import InputError
    from railgsa_ros.offline import Source
    from railgsa_ros.review.stream import run_stream
    from railgsa_ros.standards.en13848 import Limits, en13848_table

    run = run_scenario('german-low', 25.0, 12.0, 1000.0, 'ideal', 4)
    bag = _bag_with(tmp_path / 'imu_only', run, ('imu',))
    with pytest.raises(InputError, match='no odometry'):
        build_review(ReviewOptions(bag, UncertaintyConfig()))
    fixed, _ = run_stream(Source(bag), UncertaintyConfig(), None, None,
                          Limits(en13848_table(), 'd1'), speed_mps=25.0)
    grid = fixed.grid
    assert np.all(grid.speed_mps[grid.valid] == 25.0)
    assert fixed.last[1] == pytest.approx(run.chainage_m[-1] - run.chainage_m[0], abs=0.1)
