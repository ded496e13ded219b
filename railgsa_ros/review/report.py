"""The review as one self-contained HTML page (inline CSS, PNGs next to it by relative links).

Order: a summary an engineer reads in ten seconds, the map (trace, 200 m sections coloured by
their SD class, defects) and the zoomable profile (``svg_views``: inline SVG and script, works
offline), then the figures with their tables: limits and exceedances, 200 m standard deviations,
uncertainty and sensitivity, input health, truth.
"""

from __future__ import annotations

from datetime import UTC, datetime
from html import escape

import numpy as np

from railgsa_ros import __version__
from railgsa_ros.gis import Feature, sd_class
from railgsa_ros.review.exceedances import CONFIDENCES, count_by_level, describe_counts
from railgsa_ros.review.figures import loosest_limits
from railgsa_ros.review.results import Review
from railgsa_ros.standards.en13848 import LEVELS, SOURCE, LimitTable
from railgsa_ros.svg_views import CSS as SVG_CSS
from railgsa_ros.svg_views import MAP_LEGEND, SCRIPT, Mark, map_svg, profile_legend, profile_svg

MM = 1e3
MAX_ROWS = 200  # rows of the exceedance and section tables

CSS = '''
body{font-family:system-ui,-apple-system,"Segoe UI",sans-serif;max-width:1180px;margin:1.5em auto;
padding:0 1em;color:#212529;line-height:1.45}
h1{font-size:1.5em;margin-bottom:.2em}h2{font-size:1.2em;border-bottom:2px solid #dee2e6;
padding-bottom:.2em;margin-top:2em}
.sub{color:#6c757d;margin-top:0}
.cards{display:grid;grid-template-columns:repeat(auto-fill,minmax(260px,1fr));gap:.7em}
.card{border:1px solid #dee2e6;border-radius:6px;padding:.6em .8em;background:#f8f9fa}
.card b{display:block;font-size:.8em;color:#6c757d;text-transform:uppercase;letter-spacing:.03em}
.card span{font-size:1.15em}
.IAL{color:#c92a2a;font-weight:600}.IL{color:#e8590c;font-weight:600}.AL{color:#b08800}
table{border-collapse:collapse;font-size:.88em;margin:.6em 0}
th,td{border:1px solid #dee2e6;padding:.25em .6em;text-align:right}
th{background:#f1f3f5}td.l,th.l{text-align:left}
img{max-width:100%;border:1px solid #e9ecef;margin:.4em 0}
.note{font-size:.85em;color:#495057}
'''


def _mm(value: float, digits: int = 2) -> str:
    return '-' if not np.isfinite(value) else f'{value * MM:.{digits}f}'


def _table(header: list[str], rows: list[list[str]], left: int = 1) -> str:
    """An HTML table; the first ``left`` columns are left-aligned. Cells are escaped."""
    def cells(tag: str, row: list[str]) -> str:
        return ''.join(f'<{tag}{" class=l" if j < left else ""}>{escape(str(c))}</{tag}>'
                       for j, c in enumerate(row))
    body = ''.join(f'<tr>{cells("td", r)}</tr>' for r in rows)
    return f'<table><tr>{cells("th", header)}</tr>{body}</table>'


def _card(title: str, value: str) -> str:
    """A summary card; ``value`` is trusted HTML built here."""
    return f'<div class=card><b>{escape(title)}</b><span>{value}</span></div>'


def _figure(names: dict[str, str], key: str, alt: str) -> str:
    return f'<img src="{escape(names[key])}" alt="{escape(alt)}">' if key in names else ''


def _speed_classes(class_counts: np.ndarray, table: LimitTable) -> str:
    """'80 < v <= 120 km/h (100 %)' for the speed ranges met, by share of samples (counts per
    range, the last one beyond the table)."""
    values = np.flatnonzero(class_counts)
    order = values[np.argsort(-class_counts[values], kind='stable')]
    labels = [*range(class_counts.size - 1), -1]
    return ', '.join(f'{table.label(labels[i])} ({100 * class_counts[i] / class_counts.sum():.0f}'
                     ' %)' for i in order)


def _location(review: Review) -> str:
    """Line, track, km range and direction, GNSS and the odometry scale (escaped HTML)."""
    loc, run = review.location, review.run
    ref = loc.reference
    names = ', '.join(f'{k} {escape(v)}' for k, v in (('line', ref.line), ('track', ref.track))
                      if v)
    span = (f'km {float(ref.km(run.first[1])):.3f} to {float(ref.km(run.last[1])):.3f} '
            f'({ref.direction})')
    scale = loc.scale
    gnss = (f'GNSS: odometry scale {scale.value:.5f} &plusmn; {scale.std:.5f}'
            if loc.track is not None else f'no GNSS position ({escape(scale.note)})')
    return f'{names + "; " if names else ""}{span}; {gnss}'


def _summary(review: Review) -> str:
    run, health = review.run, review.health
    length = run.length_m
    v = run.grid.speed_mps[run.grid.valid] * 3.6
    peak = run.peak
    worst_level = next((e for e in sorted(review.exceedances, key=lambda e: -e.severity)
                        if e.start_m <= peak.chainage_m <= e.end_m), None)
    worst = f'{peak.value_m * MM:+.2f} mm at {review.location.reference.label(peak.chainage_m)}'
    if worst_level is not None:
        worst += f' (<span class={worst_level.level}>{worst_level.level}</span>)'
    exc = '<br>'.join(f'<span class={level}>{level}</span> {text}'
                      for level, text in describe_counts(review.exceedances).items())
    sd = review.sections.sd_m
    cards = [
        _card('run', f'{length / 1e3:.2f} km in {review.duration_s:.1f} s'),
        _card('speed', (f'{np.min(v):.0f}' if np.ptp(v) < 0.5 else
                        f'{np.min(v):.0f}-{np.max(v):.0f} (mean {np.mean(v):.0f})')
              + f' km/h; class {escape(_speed_classes(run.class_counts, review.limits.table))} '
              f'({escape(review.limits.basis)})'),
        _card('worst defect', worst),
        _card('EN 13848-5 exceedances', exc),
        _card(f'SD per {review.sections.length_m:g} m',
              f'max {_mm(np.nanmax(sd)) if np.any(np.isfinite(sd)) else "-"} mm '
              f'over {np.sum(np.isfinite(sd))} sections'),
    ]
    if run.widest is not None:
        width = (run.grid.upper_m - run.grid.lower_m)[run.grid.valid] * MM
        cards.append(_card('uncertainty (band width)',
                           f'median {np.median(width):.2f} mm (0.25 m grid), max '
                           f'{run.widest.value_m * MM:.2f} mm at '
                           f'{review.location.reference.label(run.widest.chainage_m)}'))
    cards.append(_card('input', f'{health.imu.count} IMU samples at {health.imu.rate_hz:.0f} Hz, '
                                f'{health.rejected_total} rejected, {health.imu.gaps} gaps'))
    cards.append(_card('location', _location(review)))
    if review.comparison is not None:
        s = review.comparison.score
        cards.append(_card('vs truth', f'RMSE {s.rmse * MM:.3f} mm, r = {s.correlation:.3f}, '
                                       f'peak error {s.peak_error * MM:.2f} mm'))
    return f'<div class=cards>{"".join(cards)}</div>'


def _limits_section(review: Review, names: dict[str, str]) -> str:
    lim = review.limits
    isolated, sd_range = lim.table.rows(lim.band)
    rows = [[lim.table.label(i), *(_mm(x, 0) for x in isolated[i]),
             f'{_mm(sd_range[i, 0], 1)}-{_mm(sd_range[i, 1], 1)}']
            for i in range(lim.table.upper_kmh.size)]
    table = _table(['speed range', 'AL [mm]', 'IL [mm]', 'IAL [mm]', 'SD alert range [mm]'],
                   rows)
    counts = count_by_level(review.exceedances)
    count_rows = [[level, *(str(counts[level][c]) for c in CONFIDENCES)]
                  for level in reversed(LEVELS)]
    severe = sorted(review.exceedances, key=lambda e: (-e.severity,
                                                       CONFIDENCES.index(e.confidence),
                                                       -abs(e.peak_u_m)))
    listed = sorted(severe[:MAX_ROWS], key=lambda e: e.start_m)  # the worst, in chainage order
    km = review.location.reference.km
    exc_rows = [[e.level, e.confidence, f'{float(km(e.peak_m)):.4f}', f'{e.start_m:.1f}',
                 f'{e.end_m:.1f}', f'{e.peak_m:.1f}',
                 f'{e.peak_u_m * MM:+.2f}', f'{e.lower_m * MM:+.2f} / {e.upper_m * MM:+.2f}',
                 f'{e.limit_m * MM:.0f}', f'{e.speed_kmh:.0f}', _probability(e.probability),
                 _probability(e.alert_probability)] for e in listed]
    more = (f'<p class=note>{len(severe) - MAX_ROWS} less severe ones not listed.</p>'
            if len(severe) > MAX_ROWS else '')
    band_note = ('The confidence compares the uncertainty band with the limit: certain = the '
                 'whole band passes it, likely = the reconstruction passes it but the band '
                 'reaches below, possible = only the band\'s far edge passes a limit. P = the '
                 'probability that |u| passes the limit, P(AL) that it passes the alert limit '
                 '(parameters and sensor terms)'
                 + (f'; listed when P or P(AL) >= {review.options.min_probability:g} or the '
                    'reconstruction passes the alert limit.'
                    if review.options.min_probability > 0 else '.'))
    return f'''<h2>1. Irregularity and EN 13848-5 isolated defects</h2>
{_figure(names, 'overview', 'irregularity over chainage')}
{_figure(names, 'closeups', 'close-ups of the worst defects')}
<p class=note>Mean-to-peak values of the {lim.band.upper()} band-filtered reconstruction against
the limits of the speed range at each sample: <b>{escape(lim.basis)}</b>. Limit table:
<b>{escape(lim.table.name)}</b> (AL and IL are ranges in the standard, within which the
infrastructure manager chooses; the default takes their lower end, the strictest: a screening
of a reconstruction should rather flag early than miss a defect). Standard values:
{escape(SOURCE)}.
{band_note}</p>
{_table(['level', *CONFIDENCES], count_rows)}
{_table(['level', 'confidence', 'km', 'from [m]', 'to [m]', 'peak at [m]', 'peak [mm]',
         'band at peak [mm]', 'limit [mm]', 'speed [km/h]', 'P', 'P(AL)'], exc_rows,
        left=2)}{more}
<details><summary>Limits used ({lim.band.upper()}, {escape(lim.table.name)}) [M]</summary>
{table}</details>'''


def _probability(p: float) -> str:
    return '-' if np.isnan(p) else f'{p:.2f}'


def _sections_section(review: Review, names: dict[str, str]) -> str:
    s, truth = review.sections, review.truth_sections
    sd_range = review.limits.sd_at(s.start_m + s.length_m / 2, s.speed_mps)
    truth_sd = {round(x): v for x, v in zip(truth.start_m, truth.sd_m, strict=True)} \
        if truth is not None else {}
    rows = []
    for i in range(min(len(s), MAX_ROWS)):
        status = sd_class(*(float(v) for v in (s.sd_m[i], *sd_range[i]))) or '-'
        row = [f'{s.start_m[i]:.0f}', _mm(s.sd_m[i]), f'{100 * min(s.coverage[i], 1):.0f} %',
               f'{s.speed_mps[i] * 3.6:.0f}', f'{_mm(sd_range[i, 0], 1)}-{_mm(sd_range[i, 1], 1)}',
               status]
        if truth is not None:
            row.insert(2, _mm(truth_sd.get(round(s.start_m[i]), np.nan)))
        rows.append(row)
    header = ['from [m]', 'SD [mm]', 'covered', 'speed [km/h]', 'SD alert range [mm] [M]',
              'status']
    if truth is not None:
        header.insert(2, 'truth SD [mm]')
    return f'''<h2>2. Standard deviation per {s.length_m:g} m section</h2>
{_figure(names, 'sections', 'standard deviation per section')}
<p class=note>SD of the {review.limits.band.upper()} reconstruction resampled every 0.25 m;
sections with less than half their length covered show no value. The alert ranges are the
EN 13848-5 informative annex values from secondary sources [M].</p>
{_table(header, rows, left=0)}'''


def _map_section(review: Review, features: list[Feature]) -> str:
    """The map of the GeoJSON features and the zoomable profile with its band, limits and
    exceedances."""
    grid, ref, lim = review.run.grid, review.location.reference, review.limits
    drawn = map_svg(features, f'map of {review.options.bag.name}')
    where = (drawn + MAP_LEGEND if drawn else
             '<p class=note>No GNSS position in the bag: no map (review.geojson holds the '
             'trace, sections and defects without geometry).</p>')
    band = None
    if grid.has_band:
        q = (review.config.lower_quantile, review.config.upper_quantile)
        band = f'{100 * q[0]:g}-{100 * q[1]:g} % band'
    xl, thresholds = loosest_limits(grid, lim)
    levels = [level for j, level in enumerate(LEVELS) if np.any(np.isfinite(thresholds[:, j]))]
    marks = [Mark(e.peak_m, e.peak_u_m * MM, e.level,
                  f'{e.level} ({e.confidence}) at {ref.label(e.peak_m)}: '
                  f'{e.peak_u_m * MM:+.2f} mm') for e in review.exceedances]
    profile = profile_svg(
        grid.x_m, grid.u_m * MM, label=f'{lim.band.upper()} profile', marks=marks,
        band_mm=(grid.lower_m * MM, grid.upper_m * MM) if band else None,
        limits_mm={level: (xl, thresholds[:, LEVELS.index(level)] * MM) for level in levels},
        km=(float(ref.km(0.0)), float(ref.km(1e3) - ref.km(0.0))))
    return f'''<h2>Map and profile</h2>
{where}
<p class=note>200 m sections coloured by their SD against the EN 13848-5 alert range of their
speed; defects at their peaks, coloured by level (hover for values).</p>
{profile}{profile_legend(band, levels)}'''


def _uncertainty_section(review: Review, names: dict[str, str]) -> str:
    run, cfg = review.run, review.config
    if run.design is None:
        return '<h2>3. Uncertainty and sensitivity</h2><p>No uncertain parameters: no band.</p>'
    parts = [f'<h2>3. Uncertainty and sensitivity</h2>'
             f'<p class=note>Band: {100 * cfg.lower_quantile:g}-{100 * cfg.upper_quantile:g} % '
             f'quantiles of the PCE (rule {cfg.rule}, order {cfg.order}, '
             f'{run.design.points} inverse filters as one bank) per sample; sensitivity per '
             f'window of {cfg.window_length:g} {cfg.window_unit}.</p>',
             _figure(names, 'sensitivity', 'sensitivity indices along the run')]
    if run.windows:
        rows = []
        for qoi in dict.fromkeys(w.qoi for w in run.windows):
            ws = [w for w in run.windows if w.qoi == qoi]
            for j, name in enumerate(ws[0].names):
                rows.append([qoi, name, *(f'{np.mean([getattr(w, f)[j] for w in ws]):.3f}'
                                          for f in ('sobol_first', 'sobol_total', 'delta'))])
        parts.append('<p class=note>Indices averaged over the windows:</p>'
                     + _table(['QoI', 'parameter', 'Sobol first', 'Sobol total', 'delta'], rows,
                              left=2))
    if review.worst is not None:
        w = review.worst
        res = w.result
        q = res.quantiles([cfg.lower_quantile, cfg.upper_quantile])
        rows = [[name, f'{res.sobol_first[j]:.3f}', f'{res.sobol_total[j]:.3f}']
                for j, name in enumerate(w.names)]
        parts.append(f'''{_figure(names, 'histogram', 'surrogate histogram at the worst location')}
<p class=note>Worst location {w.chainage_m:.1f} m (largest |PCE mean|): mean
{float(res.mean):+.3f} mm, std {float(res.std):.3f} mm,
{100 * cfg.lower_quantile:g}-{100 * cfg.upper_quantile:g} % interval
[{q[0]:+.3f}, {q[1]:+.3f}] mm, from {len(res.samples):,} surrogate samples.</p>
{_table(['parameter', 'Sobol first', 'Sobol total'], rows)}''')
    return '\n'.join(parts)


def _health_section(review: Review, names: dict[str, str]) -> str:
    h = review.health
    rows = [['IMU', str(h.imu.count), f'{h.imu.rate_hz:.2f}', f'{h.imu.mean_rate_hz:.2f}',
             f'{h.imu.jitter_std_s * 1e6:.1f}', f'{h.imu.jitter_max_s * 1e6:.1f}',
             str(h.imu.gaps), f'{h.imu.longest_gap_s * 1e3:.1f}', str(h.imu.backwards)]]
    if h.odom is not None:
        o = h.odom
        rows.append(['odometry', str(o.count), f'{o.rate_hz:.2f}', f'{o.mean_rate_hz:.2f}',
                     f'{o.jitter_std_s * 1e6:.1f}', f'{o.jitter_max_s * 1e6:.1f}', str(o.gaps),
                     f'{o.longest_gap_s * 1e3:.1f}', str(o.backwards)])
    stamps = _table(['topic', 'messages', 'rate [Hz]', 'mean rate [Hz]', 'jitter std [us]',
                     'jitter max [us]', 'gaps', 'longest gap [ms]', 'steps <= 0'], rows)
    counters = _table(['counter', 'count'], [[k, str(v)] for k, v in sorted(h.counters.items())])
    findings = _table(['check', 'level', 'finding'],
                      [[f.key, ('OK', 'WARN', 'ERROR')[f.level], f.message]
                       for f in review.run.findings], left=3)
    odom = ('no odometry: the configured speed was used' if h.odom is None else
            f'speed {h.speed_min_mps * 3.6:.0f}-{h.speed_max_mps * 3.6:.0f} km/h')
    return f'''<h2>4. Input health</h2>
{_figure(names, 'health', 'input health')}
<p class=note>Stamps from the {escape(h.stamp_source)}; {odom}. Gaps: steps above
{h.gap_factor:g} nominal periods. The counters are the streaming
pipeline's own (rejected samples by reason, gaps, resets, emitted); the findings are the
input policy's checks at the end of the run (mounting tilt, rate, gravity, speed, ...).</p>
{stamps}{counters}{findings}'''


def _truth_section(review: Review, names: dict[str, str]) -> str:
    c = review.comparison
    if c is None:
        return ''
    s = c.score
    rows = [['RMSE', f'{s.rmse * MM:.3f} mm'], ['correlation', f'{s.correlation:.4f}'],
            ['peak error at the largest defect', f'{s.peak_error * MM:.3f} mm at '
                                                 f'{c.defect_m:.1f} m'],
            ['scored samples (0.25 m)', str(s.n)]]
    return f'''<h2>5. Against the truth</h2>
{_figure(names, 'truth', 'reconstruction against truth')}
<p class=note>Truth from {escape(str(review.options.truth))}, filtered to the same
{review.limits.band.upper()} band on distance (inverse.score); 100 m are left out at both
ends.</p>{_table(['score', 'value'], rows)}'''


def _footer(review: Review) -> str:
    cfg, inv = review.config, review.config.inversion
    t = review.timings
    total = sum(t.values())
    speed = review.duration_s / total if total > 0 else float('nan')
    stages = ', '.join(f'{k} {v:.2f} s' for k, v in t.items())
    vehicle = ', '.join(f'{k} {v:g}' for k, v in review.options.vehicle.as_dict().items())
    uncertain = ', '.join(review.options.dists or {}) or 'none'
    return f'''<h2>Settings</h2><p class=note>Method {inv.method}, band {inv.band}, gap policy
{inv.gap_policy}, band delay {review.run.delay_samples} samples; vehicle {vehicle}; uncertain
{escape(uncertain)}; rule {cfg.rule}. Review time {total:.1f} s ({stages}):
{speed:.0f}x real time. railgsa_ros {__version__}.</p>'''


def render_html(review: Review, names: dict[str, str], features: list[Feature]) -> str:
    """The report page; ``names`` maps figure keys to PNG file names in the same directory,
    ``features`` are the GeoJSON features of the map (``outputs.features``)."""
    bag = review.options.bag
    start = datetime.fromtimestamp(review.run.first[0] / 1e9, UTC)
    body = '\n'.join([
        f'<h1>Track irregularity review: {escape(bag.name)}</h1>',
        f'<p class=sub>{escape(str(bag))} &middot; first stamp {start:%Y-%m-%d %H:%M:%S} UTC '
        f'&middot; EN 13848 {review.limits.band.upper()}, method '
        f'{escape(review.config.inversion.method)}</p>',
        _summary(review), _map_section(review, features), _limits_section(review, names),
        _sections_section(review, names),
        _uncertainty_section(review, names), _health_section(review, names),
        _truth_section(review, names), _footer(review)])
    return (f'<!DOCTYPE html>\n<html lang=en><head><meta charset=utf-8>'
            f'<meta name=viewport content="width=device-width,initial-scale=1">'
            f'<title>Review {escape(bag.name)}</title><style>{CSS}{SVG_CSS}</style></head>'
            f'<body>\n{body}\n<script>{SCRIPT}</script>\n</body></html>\n')
