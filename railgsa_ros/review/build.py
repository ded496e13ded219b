"""A review end to end: read the bag, run the streaming core, analyse, write DIR/report.html.

``build_review`` computes everything (no file written); ``write_review`` draws the figures and
writes the HTML into a temporary directory that replaces DIR only when all of it succeeded.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
import time

from railgsa_ros.fileio import atomic_output
from railgsa_ros.review import figures
from railgsa_ros.review.exceedances import Exceedance, listed
from railgsa_ros.review.figures import ZOOM_M
from railgsa_ros.review.outputs import write_outputs
from railgsa_ros.review.report import render_html
from railgsa_ros.review.results import Review, ReviewOptions
from railgsa_ros.review.stream import run_stream
from railgsa_ros.review.truth import DX_M, check_truth, compare, truth_on_grid
from railgsa_ros.review.worst import plot_worst, worst_surrogate
from railgsa_ros.standards.en13848 import Limits, en13848_table
from railgsa_ros.standards.sections import grid_sections, section_sd

REPORT = 'report.html'
Progress = Callable[[str, float], None]  # (stage, fraction done)


def build_review(options: ReviewOptions, progress: Progress | None = None) -> Review:
    """Stream and analyse; InputError naming the file for unusable bags or truth."""
    def tick(stage: str, fraction: float) -> None:
        if progress is not None:
            progress(stage, fraction)

    timings: dict[str, float] = {}
    start = time.perf_counter()
    tick('reading', 0.0)
    limits = Limits(options.limits or en13848_table(options.limit_end),
                    options.config.inversion.band, options.line_speed)
    truth = check_truth(options.truth) if options.truth is not None else None
    source = options.source  # one Source: it reads the bag's index once
    total = max(source.count(options.imu_topic), 1)
    run, cfg = run_stream(source, options.config, options.vehicle, options.dists,
                          limits, options.reference, options.rate_from_bag, options.section_m,
                          progress=lambda done: tick('processing', min(done / total, 1.0)))
    timings['stream'] = time.perf_counter() - start
    tick('analysing', 1.0)
    mark = time.perf_counter()
    grid = run.grid
    sections = grid_sections(grid.x_m, grid.u_m, grid.valid, run.section_speeds,
                             options.section_m, grid.dx_m)
    comparison = truth_sections = None
    if options.truth is not None:
        truth = truth_on_grid(options.truth, *run.first) if truth is None else truth
        comparison = compare(grid.x_m[grid.valid], grid.u_m[grid.valid], truth, cfg.inversion.band)
        truth_sections = section_sd(comparison.x_m, comparison.truth_m, None, options.section_m,
                                    max_step_m=2 * DX_M)
    worst = None
    if run.worst is not None and run.design is not None:
        worst = worst_surrogate(run.design, run.worst, cfg)
    timings['analyse'] = time.perf_counter() - mark
    kept = listed(run.exceedances, options.min_probability)
    return Review(options, cfg, run, run.health, run.limits, kept, sections,
                  truth_sections, comparison, worst, timings)


def closeup_centres(review: Review, count: int = 4) -> tuple[list[float], list[str]]:
    """Chainages (m) and titles of the worst exceedances (by level, then |peak|; one per
    close-up width), or of the largest |u| when nothing exceeds."""
    ranked = sorted(review.exceedances, key=lambda e: (-e.severity, -abs(e.peak_u_m)))
    picked: list[Exceedance] = []
    for e in ranked:
        if len(picked) < count and all(abs(e.peak_m - p.peak_m) > ZOOM_M for p in picked):
            picked.append(e)
    where = review.location.reference.label
    if picked:
        return ([e.peak_m for e in picked],
                [f'{e.level} ({e.confidence}) at {where(e.peak_m)}: {e.peak_u_m * 1e3:+.2f} mm'
                 for e in picked])
    peak = review.run.peak
    return [peak.chainage_m], [f'largest |u| at {where(peak.chainage_m)}: '
                               f'{peak.value_m * 1e3:+.2f} mm (no exceedance)']


def draw_figures(review: Review, folder: Path) -> dict[str, str]:
    """Every PNG of the report into ``folder``; returns figure key -> file name."""
    run, q = review.run, (review.config.lower_quantile, review.config.upper_quantile)
    made = {
        'overview': figures.plot_overview(folder / 'overview.png', run.grid, review.limits,
                                          review.exceedances, q, review.location.reference),
        'closeups': figures.plot_closeups(folder / 'closeups.png', run.grid, review.limits,
                                          *closeup_centres(review), q),
        'sections': figures.plot_sections(folder / 'sections.png', review.sections,
                                          review.limits, review.location.reference,
                                          review.truth_sections),
        'health': figures.plot_health(folder / 'health.png', review.health),
    }
    if run.windows:
        made['sensitivity'] = figures.plot_sensitivity(folder / 'sensitivity.png', run.windows)
    if review.worst is not None:
        made['histogram'] = plot_worst(folder / 'histogram.png', review.worst)
    if review.comparison is not None:
        made['truth'] = figures.plot_truth(folder / 'truth.png', review.comparison,
                                           review.limits.band)
    return {key: path.name for key, path in made.items()}


def write_review(review: Review, out_dir: str | Path, overwrite: bool = False,
                 progress: Progress | None = None) -> Path:
    """Write DIR/report.html with its PNGs, defects.csv, sections.csv and review.geojson
    atomically; returns the report's path."""
    start = time.perf_counter()
    with atomic_output(out_dir, overwrite) as tmp:
        tmp.mkdir()
        if progress is not None:
            progress('drawing', 1.0)
        names = draw_figures(review, tmp)
        features = write_outputs(review, tmp)
        review.timings['figures'] = time.perf_counter() - start
        (tmp / REPORT).write_text(render_html(review, names, features), encoding='utf-8')
    return Path(out_dir) / REPORT
