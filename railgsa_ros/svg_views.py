"""The reports' interactive views as inline SVG: a map of a run's GeoJSON and a zoomable
profile. Self-contained and offline: no tile server, no CDN, no library.

Each view is an ``svg.zoom`` holding an ``svg.view`` whose viewBox is in data units (map: metres
east and up-is-north of the features' centre; profile: chainage in m and minus the depth in mm,
so that up is up). ``SCRIPT``, a few lines of JavaScript written for these pages (a library
would be a file to ship and to trust for what a wheel and a drag do), zooms about the pointer
with the wheel (profile: along the track, shift + wheel: the depth; map: both), pans by a
drag, resets on a double click, and redraws the profile's axes (km-posts, mm) and the map's
scale bar. Strokes do not scale with the zoom; markers are zero-length round-capped strokes,
so they stay round dots in a profile stretched along the track.

Map projection: equirectangular about the centre of the features, a sketch whose scale is
off by about tan(lat0) times the latitude difference in radians (0.4 % 20 km north of the
centre at 52 deg); the GeoJSON keeps the exact positions. A profile longer than ``BINS``
cells is drawn as its min/max envelope (every peak kept at any zoom, the page's size bounded).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from html import escape
import math
from typing import Any

import numpy as np

from railgsa_ros.envelope import envelope
from railgsa_ros.gis import SD_CLASSES, Feature

BINS = 3000  # envelope bins of a profile: 2 x 3000 points per curve at most
EARTH_R_M = 6371008.8  # mean radius, m
MAP_W, MAP_H, MAP_PAD = 1000, (200, 440), 20  # width, least and largest drawn height
PLOT_W, PLOT_H = 1000, 330
PLOT_BOX = (58, 8, 930, 290)  # x, y, width, height of the plot area in the profile
#: CSS class of each section class (gis.SD_CLASSES), None: no SD or no alert range
SECTION_CSS: dict[str | None, str] = {**dict(zip(SD_CLASSES, ('below', 'alert', 'above'),
                                                  strict=True)), None: 'none'}

LEVEL_COLOURS = {'AL': '#e0a800', 'IL': '#e8590c', 'IAL': '#c92a2a', 'none': '#495057'}
SECTION_COLOURS = {'below': '#2b8a3e', 'alert': '#e0a800', 'above': '#c92a2a', 'none': '#adb5bd'}
TRACE_COLOUR, LINE_COLOUR, BAND_COLOUR = '#868e96', '#1c3d5a', '#74c0fc'

CSS = ('''
svg.zoom{width:100%;height:auto;border:1px solid #dee2e6;background:#fcfcfd;
touch-action:none;cursor:grab;user-select:none}
svg.view path{vector-effect:non-scaling-stroke;fill:none;stroke-linejoin:round;
stroke-linecap:round}
.section{stroke-width:3.5}.mark{stroke-width:11}.ring{stroke:#212529;stroke-width:16}
.limit{stroke-width:1;stroke-dasharray:5 3}
g.axes line{stroke:#dee2e6;stroke-width:1}g.axes text,.scale text,.north text,.name{font-size:12px;
fill:#495057;font-family:system-ui,sans-serif}g.axes text.y{text-anchor:end}
g.axes text.x{text-anchor:middle}.scale rect,.north path{fill:#495057}
.legend span{display:inline-block;margin-right:1.2em;font-size:.85em}
.legend i{display:inline-block;width:1.6em;height:.35em;vertical-align:middle;margin-right:.3em}
.legend i.dot{width:.7em;height:.7em;border-radius:50%}
''' + f'''.trace{{stroke:{TRACE_COLOUR};stroke-width:7;stroke-opacity:.45}}
.u{{stroke:{LINE_COLOUR};stroke-width:1}}
svg.view path.band{{fill:{BAND_COLOUR};fill-opacity:.5;stroke:none}}
''' + ''.join(f'.section.{k}{{stroke:{c}}}' for k, c in SECTION_COLOURS.items())
       + ''.join(f'.mark.{k},.limit.{k}{{stroke:{c}}}' for k, c in LEVEL_COLOURS.items()))

SCRIPT = '''
(function () {
  var NS = 'http://www.w3.org/2000/svg';
  function step(span, n) {  // a round step (1, 2 or 5 x 10^k) for about n ticks over span
    var s = Math.pow(10, Math.floor(Math.log10(span / n))), m = span / n / s;
    return s * (m < 1.5 ? 1 : m < 3.5 ? 2 : m < 7.5 ? 5 : 10);
  }
  function digits(st) { return Math.max(0, Math.ceil(-Math.log10(st) - 1e-9)); }
  function add(g, tag, attrs, text) {
    var e = document.createElementNS(NS, tag);
    for (var k in attrs) e.setAttribute(k, attrs[k]);
    if (text !== undefined) e.textContent = text;
    g.appendChild(e);
  }
  function axes(svg, view, b) {  // km-posts below, mm on the left, grid lines
    var X = view.x.baseVal.value, Y = view.y.baseVal.value;
    var W = view.width.baseVal.value, H = view.height.baseVal.value;
    var g = svg.querySelector('g.axes'), km0 = +svg.dataset.km0, sign = +svg.dataset.sign;
    g.textContent = '';
    var sk = step(b.width / 1000, 8), sy = step(b.height, 6), i, px, py;
    var ends = [km0 + sign * b.x / 1000, km0 + sign * (b.x + b.width) / 1000];
    for (i = Math.ceil(Math.min.apply(null, ends) / sk); i * sk <= Math.max.apply(null, ends);
         i++) {  // round km-posts, at their chainage
      px = X + ((i * sk - km0) * 1000 * sign - b.x) / b.width * W;
      add(g, 'line', {x1: px, x2: px, y1: Y, y2: Y + H});
      add(g, 'text', {x: px, y: Y + H + 15, 'class': 'x'}, (i * sk).toFixed(digits(sk)));
    }
    for (i = Math.ceil(b.y / sy); i * sy <= b.y + b.height; i++) {
      py = Y + (i * sy - b.y) / b.height * H;
      add(g, 'line', {x1: X, x2: X + W, y1: py, y2: py});
      add(g, 'text', {x: X - 5, y: py + 4, 'class': 'y'}, (-i * sy).toFixed(digits(sy)));
    }
  }
  function scale(svg, view, b) {  // a round length as a bar of 100-250 px
    var px = Math.min(view.width.baseVal.value / b.width, view.height.baseVal.value / b.height);
    var m = step(150 / px, 1);
    svg.querySelector('.scale rect').setAttribute('width', m * px);
    svg.querySelector('.scale text').textContent = m >= 1000 ? m / 1000 + ' km' : m + ' m';
  }
  function setup(svg) {
    var view = svg.querySelector('svg.view'), both = svg.dataset.zoom === 'xy';
    var home = view.getAttribute('viewBox'), last = null;
    function draw() {
      (svg.dataset.km0 === undefined ? scale : axes)(svg, view, view.viewBox.baseVal);
    }
    function at(e) {  // the data point under the pointer
      var p = svg.createSVGPoint();
      p.x = e.clientX; p.y = e.clientY;
      return p.matrixTransform(view.getScreenCTM().inverse());
    }
    svg.addEventListener('wheel', function (e) {
      e.preventDefault();
      var b = view.viewBox.baseVal, p = at(e), f = Math.exp(e.deltaY * 0.002);
      if (both || !e.shiftKey) { b.x = p.x - (p.x - b.x) * f; b.width *= f; }
      if (both || e.shiftKey) { b.y = p.y - (p.y - b.y) * f; b.height *= f; }
      draw();
    }, {passive: false});
    svg.addEventListener('pointerdown', function (e) {
      last = e; svg.setPointerCapture(e.pointerId);
    });
    svg.addEventListener('pointermove', function (e) {
      if (!last) return;
      var m = view.getScreenCTM(), b = view.viewBox.baseVal;
      b.x -= (e.clientX - last.clientX) / m.a;
      if (both || e.shiftKey) b.y -= (e.clientY - last.clientY) / m.d;
      last = e; draw();
    });
    svg.addEventListener('pointerup', function () { last = null; });
    svg.addEventListener('dblclick', function () { view.setAttribute('viewBox', home); draw(); });
    draw();
  }
  document.querySelectorAll('svg.zoom').forEach(setup);
})();
'''


def _num(v: float, digits: int) -> str:
    """A coordinate: fixed digits, no trailing zeros."""
    text = f'{v:.{digits}f}'
    return text.rstrip('0').rstrip('.') if '.' in text else text


def path_data(x: np.ndarray, y: np.ndarray, digits: tuple[int, int] = (2, 3)) -> str:
    """SVG path data through the points (x, y); a new subpath after every NaN."""
    ok = np.isfinite(x) & np.isfinite(y)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(np.int8), [0]])))
    return ''.join('M' + ' '.join(f'{_num(a, digits[0])} {_num(b, digits[1])}'
                                  for a, b in zip(x[lo:hi], y[lo:hi], strict=True))
                   for lo, hi in zip(edges[::2], edges[1::2], strict=True))


def _tag(name: str, attrs: Mapping[str, Any], body: str = '') -> str:
    """An element with escaped attribute values."""
    text = ''.join(f' {k}="{escape(str(v))}"' for k, v in attrs.items())
    return f'<{name}{text}>{body}</{name}>'


def _title(text: str) -> str:
    return f'<title>{escape(text)}</title>'


def _dot(start: str, level: str, title: str, new: bool) -> str:
    """A marker at the path's start point (a zero-length round-capped stroke), ringed when new,
    with its tooltip."""
    ring = _tag('path', {'class': 'ring', 'd': start + 'h0'}) if new else ''
    return ring + _tag('path', {'class': f'mark {level}', 'd': start + 'h0'}, _title(title))


def legend(items: Sequence[tuple[str, str, bool]]) -> str:
    """An HTML legend: (CSS colour, label, dot or line) per item."""
    return '<div class=legend>' + ''.join(
        f'<span><i class="{"dot" if dot else "line"}" style="background:{colour}"></i>'
        f'{escape(label)}</span>' for colour, label, dot in items) + '</div>'


# --- map -------------------------------------------------------------------------------------

def _lines(geometry: dict[str, Any]) -> list[np.ndarray]:
    """The (n, 2) lon/lat arrays of a (Multi)LineString or Point."""
    kind, coords = geometry['type'], geometry['coordinates']
    parts = {'Point': [[coords]], 'LineString': [coords]}.get(kind, coords)
    return [np.asarray(p, dtype=float) for p in parts]


def _section_title(p: Mapping[str, Any]) -> str:
    sd = 'no SD' if p.get('sd_mm') is None else f'SD {p["sd_mm"]:.2f} mm'
    return (f'km {p["start_km"]:.3f}-{p["end_km"]:.3f}: {sd} '
            f'({p.get("class") or "no alert range"})')


def _defect_title(p: Mapping[str, Any]) -> str:
    new = ' NEW' if p.get('new') else ''
    return f'{p.get("level") or "below AL"}{new} at km {p["km"]:.4f}: {p["depth_mm"]:+.2f} mm'


def map_svg(features: Sequence[Feature], label: str) -> str:
    """The features (``gis``: trace, sections, defects) as a zoomable map; '' when none has a
    position."""
    placed = [f for f in features if f['geometry'] is not None]
    if not placed:
        return ''
    every = np.concatenate([p for f in placed for p in _lines(f['geometry'])])
    lon0, lat0 = (every.min(0) + every.max(0)) / 2
    k = math.radians(1) * EARTH_R_M

    def xy(lonlat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return ((lonlat[:, 0] - lon0) * k * math.cos(math.radians(lat0)),
                -(lonlat[:, 1] - lat0) * k)

    def d(f: Feature) -> str:
        return ''.join(path_data(*xy(p), (1, 1)) for p in _lines(f['geometry']))

    ex, ey = xy(every)
    pad = 0.04 * max(np.ptp(ex), np.ptp(ey), 50.0)
    w, h = np.ptp(ex) + 2 * pad, np.ptp(ey) + 2 * pad
    box = f'{ex.min() - pad:.1f} {ey.min() - pad:.1f} {w:.1f} {h:.1f}'
    height = int(np.clip((MAP_W - 2 * MAP_PAD) * h / w, *MAP_H)) + 2 * MAP_PAD
    kinds: dict[str, list[str]] = {'trace': [], 'section': [], 'defect': []}
    for f in placed:
        p = f['properties']
        if p['kind'] == 'trace':
            kinds['trace'].append(_tag('path', {'class': 'trace', 'd': d(f)}))
        elif p['kind'] == 'section':
            kinds['section'].append(_tag('path', {'class': f'section {SECTION_CSS[p["class"]]}',
                                                  'd': d(f)}, _title(_section_title(p))))
        else:
            kinds['defect'].append(_dot(d(f), p.get('level') or 'none', _defect_title(p),
                                        bool(p.get('new'))))
    view = _tag('svg', {'class': 'view', 'x': MAP_PAD, 'y': MAP_PAD, 'width': MAP_W - 2 * MAP_PAD,
                        'height': height - 2 * MAP_PAD, 'viewBox': box,
                        'preserveAspectRatio': 'xMidYMid meet'},
                ''.join(kinds['trace'] + kinds['section'] + kinds['defect']))
    scale = (f'<g class=scale><rect x="{MAP_PAD}" y="{height - 16}" width="100" height="4"/>'
             f'<text x="{MAP_PAD}" y="{height - 22}"></text></g>')
    north = (f'<g class=north><path d="M{MAP_W - 30} {MAP_PAD}l-6 14h12z"/>'
             f'<text x="{MAP_W - 30}" y="{MAP_PAD + 30}" text-anchor=middle>N</text></g>')
    return _tag('svg', {'class': 'zoom map', 'viewBox': f'0 0 {MAP_W} {height}',
                        'data-zoom': 'xy', 'role': 'img', 'aria-label': label},
                view + scale + north)


MAP_LEGEND = legend([(TRACE_COLOUR, 'trace', False),
                     *((SECTION_COLOURS[SECTION_CSS[c]], f'SD {c}', False) for c in SD_CLASSES),
                     (SECTION_COLOURS['none'], 'no SD or no alert range', False),
                     *((LEVEL_COLOURS[k], k, True) for k in ('AL', 'IL', 'IAL')),
                     (LEVEL_COLOURS['none'], 'below AL', True)])


# --- profile ---------------------------------------------------------------------------------

@dataclass(frozen=True)
class Mark:
    """A marker on the profile: chainage (m), value (mm), level (CSS class), tooltip and
    whether it is new (ringed)."""

    x_m: float
    y_mm: float
    level: str
    title: str
    new: bool = False


def _curve(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A long curve as its envelope, each bin's min then max (a zigzag that fills the band the
    signal sweeps); short ones as they are."""
    xe, lo, hi = envelope(x, y, bins=BINS)
    if xe.size == x.size:
        return x, np.asarray(y, float)
    return np.repeat(xe, 2), np.column_stack([lo, hi]).ravel()


def _area(x: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> str:
    """A band between two curves: one closed polygon per stretch without NaN."""
    xe, lo, _, _, hi = envelope(x, lower, upper, bins=BINS)
    ok = np.isfinite(lo) & np.isfinite(hi)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(np.int8), [0]])))
    return ''.join(path_data(np.concatenate([xe[a:b], xe[a:b][::-1]]),
                             -np.concatenate([hi[a:b], lo[a:b][::-1]])) + 'Z'
                   for a, b in zip(edges[::2], edges[1::2], strict=True))


def profile_svg(x_m: np.ndarray, u_mm: np.ndarray, *, label: str,
                band_mm: tuple[np.ndarray, np.ndarray] | None = None,
                limits_mm: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None,
                marks: Sequence[Mark] = (), km: tuple[float, float] = (0.0, 1.0)) -> str:
    """A zoomable profile u (mm) over chainage x (m) with its band (lower, upper) mm, limit
    lines +-value (mm) at chainages (m) per level, and markers; the axis shows km-posts
    ``km[0] + km[1] * x / 1000``. '' when u has no finite value."""
    x = np.asarray(x_m, dtype=float)
    u = np.asarray(u_mm, dtype=float)
    if not np.any(np.isfinite(u)):
        return ''
    parts = [] if band_mm is None else [_tag('path', {'class': 'band',
                                                      'd': _area(x, *band_mm)})]
    reach = [np.nanmax(np.abs(u))]
    if band_mm is not None and np.any(np.isfinite(band_mm[0])):
        reach.append(np.nanmax(np.abs(np.concatenate(band_mm))))
    for level, (lx, value) in (limits_mm or {}).items():
        if np.any(np.isfinite(value)):
            reach.append(np.nanmax(value))
            parts += [_tag('path', {'class': f'limit {level}', 'd': path_data(lx, s * value)})
                      for s in (-1, 1)]
    parts.append(_tag('path', {'class': 'u', 'd': path_data(*_curve(x, -u))}))
    parts += [_dot(f'M{_num(m.x_m, 2)} {_num(-m.y_mm, 3)}', m.level, m.title, m.new)
              for m in marks]
    top = 1.08 * max(reach)
    lo, hi = np.nanmin(x), np.nanmax(x)
    bx, by, bw, bh = PLOT_BOX
    view = _tag('svg', {'class': 'view', 'x': bx, 'y': by, 'width': bw, 'height': bh,
                        'viewBox': f'{lo:.2f} {-top:.3f} {max(hi - lo, 1.0):.2f} {2 * top:.3f}',
                        'preserveAspectRatio': 'none'}, ''.join(parts))
    frame = f'<rect x="{bx}" y="{by}" width="{bw}" height="{bh}" fill="none" stroke="#adb5bd"/>'
    names = (f'<text class=name x="{bx + bw / 2}" y="{PLOT_H - 4}" text-anchor=middle>'
             f'km-post</text><text class=name x="12" y="{by + bh / 2}" text-anchor=middle '
             f'transform="rotate(-90 12 {by + bh / 2})">mm</text>')
    return _tag('svg', {'class': 'zoom profile', 'viewBox': f'0 0 {PLOT_W} {PLOT_H}',
                        'data-zoom': 'x', 'data-km0': km[0], 'data-sign': km[1], 'role': 'img',
                        'aria-label': label}, '<g class=axes></g>' + view + frame + names)


def profile_legend(band: str | None, levels: Sequence[str]) -> str:
    """The legend of a profile: the curve, its band, the limit levels drawn and the markers."""
    items = [(LINE_COLOUR, 'profile', False)]
    if band is not None:
        items.append((BAND_COLOUR, band, False))
    items += [(LEVEL_COLOURS[level], f'+-{level}', False) for level in levels]
    items += [(LEVEL_COLOURS[level], f'{level} defect', True) for level in levels]
    return legend(items) + ('<p class=note>Wheel: zoom along the track; shift + wheel: zoom the '
                            'depth; drag: pan; double click: back to the whole run.</p>')
