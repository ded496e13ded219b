"""The HTML reports in a real headless browser (Chromium): the map and the zoomable profile that
the page's own script builds, checked on the DOM the browser renders and on a screenshot.

Data: ``railgsa simulate-passes`` (two passes over a line with a known geometry and GNSS in every
bag; one dip past the intervention limit, its section's SD past the alert range, and one that
appears in the second pass), reviewed (``railgsa review``) and ingested and reported by the
fleet (``railgsa fleet ingest/report``), all through the command line. The truth: the
simulation's line geometry, the CSV and GeoJSON files beside the reports (what the map must
draw) and the zoom arithmetic of the script.

Skipped when no Chromium is installed (``apt-get install chromium``: 460 MB, so the project's
set-up does not install it).
"""

from __future__ import annotations

import csv
from html.parser import HTMLParser
import json
import math
from pathlib import Path
import shutil
import subprocess

import numpy as np
import pytest

from railgsa_ros.cli.main import main
from railgsa_ros.fleet.gnss import load_geometry

BROWSER = next((shutil.which(n) for n in ('chromium', 'chromium-browser', 'google-chrome')
                if shutil.which(n)), None)
pytestmark = pytest.mark.skipif(BROWSER is None,
                                reason='no headless browser (apt-get install chromium)')
DEFECTS = 'dip@600:len=8:depth=3e-2,dip@1000:len=6:depth=7e-3:from=2'
GNSS_M = 3.0  # the trace's distance from the true line: 2 m GNSS noise, smoothed over 50 m
KM0 = 7.5  # km-post of the review's start, decreasing along the run


def km(chainage_m: float) -> float:
    """The review's km-post of a chainage."""
    return KM0 - chainage_m / 1e3


def browser(page: Path, *args: str, cwd: Path | None = None) -> str:
    """Run headless Chromium on a local page; its stdout (the DOM with --dump-dom)."""
    profile = page.parent / '.chromium-profile'
    result = subprocess.run([BROWSER, '--headless', '--no-sandbox', '--disable-gpu',
                             '--hide-scrollbars', f'--user-data-dir={profile}', *args,
                             page.resolve().as_uri()], capture_output=True, text=True,
                            timeout=180, cwd=cwd)
    assert result.returncode == 0, result.stderr[-2000:]
    return result.stdout


class Elements(HTMLParser):
    """Every element of a page as (tag, attributes, classes of its ancestors, text)."""

    def __init__(self, text: str) -> None:
        super().__init__()
        self.found: list[dict] = []
        self._open: list[dict] = []
        self.feed(text)

    def handle_starttag(self, tag: str, attrs: list) -> None:
        element = {'tag': tag, 'attrs': dict(attrs), 'text': '',
                   'within': ' '.join(e['attrs'].get('class') or '' for e in self._open)}
        self.found.append(element)
        self._open.append(element)

    def handle_endtag(self, tag: str) -> None:
        while self._open and self._open.pop()['tag'] != tag:
            pass

    def handle_data(self, data: str) -> None:
        if self._open:
            self._open[-1]['text'] += data

    def select(self, tag: str, cls: str, within: str) -> list[dict]:
        """Elements ``tag`` whose class list has ``cls`` (any class: '') inside an element of
        class ``within``."""
        return [e for e in self.found if e['tag'] == tag and within in e['within']
                and (not cls or cls in (e['attrs'].get('class') or '').split())]


@pytest.fixture(scope='module')
def reports(tmp_path_factory) -> Path:
    """The series, its review (pass 1) and its fleet report under one folder."""
    root = tmp_path_factory.mktemp('html')
    passes = root / 'passes'
    assert main(['simulate-passes', '--out', str(passes), '--passes', '2', '--section-km',
                 '0.3-1.5', '--rate', '200', '--defects', DEFECTS]) == 0
    assert main(['review', str(passes / 'pass_01'), '--out', str(root / 'review'),
                 '--no-uncertainty', '--no-progress', '--km-origin', str(KM0), '--direction',
                 'decreasing']) == 0
    assert main(['fleet', 'ingest', *map(str, sorted(passes.glob('pass_*'))), '--db',
                 str(root / 'fleet.duckdb'), '--line', 'sim-1', '--line-geometry',
                 str(passes / 'line.geojson'), '--workers', '1']) == 0
    assert main(['fleet', 'report', '--db', str(root / 'fleet.duckdb'), '--out',
                 str(root / 'fleet')]) == 0
    return root


def features(path: Path, kind: str) -> list[dict]:
    return [f for f in json.loads(path.read_text())['features']
            if f['properties']['kind'] == kind]


def test_geojson_trace_and_sections_lie_on_the_true_line_in_lon_lat_order(reports) -> None:
    line = load_geometry(reports / 'passes' / 'line.geojson')
    for geojson in (reports / 'review' / 'review.geojson', reports / 'fleet' / 'fleet.geojson'):
        (trace,) = features(geojson, 'trace')
        sections = features(geojson, 'section')
        for f in [trace, *sections]:
            assert f['geometry']['type'] == 'LineString'
            lon, lat = np.array(f['geometry']['coordinates']).T  # RFC 7946: lon, lat
            _, cross = line.locate(lat, lon)
            assert np.all(np.abs(cross) < GNSS_M), geojson
        along, _ = line.locate(*np.array(trace['geometry']['coordinates'])[:, ::-1].T)
        assert np.ptp(along) > 1000.0  # the whole run, simplified to a few vertices
        assert len(trace['geometry']['coordinates']) < 60
        for s in sections:  # a section's line spans its 200 m (the first and last: clipped)
            lon, lat = np.array(s['geometry']['coordinates']).T
            x, _ = line.locate(lat, lon)
            assert np.ptp(x) <= 200.0 + GNSS_M
            if s not in (sections[0], sections[-1]):
                assert np.ptp(x) == pytest.approx(200.0, abs=GNSS_M)
        assert {s['properties']['class'] for s in sections} <= {'below', 'in alert range',
                                                                'above alert range'}


def limit_classes(dom: Elements) -> list[str]:
    """The levels of the profile's limit lines, sorted."""
    return sorted(e['attrs']['class'].split()[1] for e in dom.select('path', 'limit',
                                                                     'zoom profile'))


def test_review_map_and_profile_in_the_browser(reports) -> None:
    folder = reports / 'review'
    dom = Elements(browser(folder / 'report.html', '--dump-dom'))
    with (folder / 'sections.csv').open() as f:
        sections = list(csv.DictReader(f))
    with (folder / 'defects.csv').open() as f:
        defects = list(csv.DictReader(f))
    assert any(d['level'] == 'IL' for d in defects)  # the 30 mm dip (20 mm in D1)
    assert len(dom.select('path', 'trace', 'zoom map')) == 1
    drawn = dom.select('path', 'section', 'zoom map')
    assert len(drawn) == len(sections) == len(features(folder / 'review.geojson', 'section'))
    classes = [e['attrs']['class'].split()[1] for e in drawn]
    assert 'alert' in classes or 'above' in classes  # the section with the dip
    assert len(dom.select('path', 'mark', 'zoom map')) == len(defects)
    assert len(dom.select('path', 'mark', 'zoom profile')) == len(defects)
    assert limit_classes(dom) == ['AL', 'AL', 'IAL', 'IAL', 'IL', 'IL']  # +- each limit
    # the script ran: km-post ticks along the run (km 7.5 down to 6.25), each where its km-post
    # is, and a scale bar
    (view,) = dom.select('svg', 'view', 'zoom profile')
    x0, _, width, _ = map(float, view['attrs']['viewbox'].split())
    pixel = width / float(view['attrs']['width'])  # m
    ticks = dom.select('text', 'x', 'zoom profile')
    assert len(ticks) >= 4
    for t in ticks:
        at = x0 + (float(t['attrs']['x']) - float(view['attrs']['x'])) * pixel
        assert float(t['text']) == pytest.approx(km(at), abs=pixel / 1e3)
        assert km(1300.0) <= float(t['text']) <= KM0
    assert dom.select('text', '', 'scale')[0]['text'].endswith(' m')


ZOOM = '''<script>
function vb(s) { var b = document.querySelector(s + ' svg.view').viewBox.baseVal;
                 return [b.x, b.y, b.width, b.height]; }
function wheel(s, shift) {
  var r = document.querySelector(s + ' svg.view').getBoundingClientRect();  // the plot's centre
  document.querySelector(s).dispatchEvent(new WheelEvent('wheel', {deltaY: -100,
      clientX: r.left + r.width / 2, clientY: r.top + r.height / 2, shiftKey: shift,
      bubbles: true, cancelable: true}));
  return vb(s);
}
var p = 'svg.profile', m = 'svg.map', out = {home: vb(p), map: vb(m)};
out.x = wheel(p, false); out.y = wheel(p, true); out.mapZoom = wheel(m, false);
out.ticks = Array.from(document.querySelectorAll(p + ' g.axes text.x'), t => t.textContent);
document.querySelector(p).dispatchEvent(new MouseEvent('dblclick', {bubbles: true}));
out.reset = vb(p);
document.body.dataset.zoom = JSON.stringify(out);
</script></body>'''


def test_wheel_zooms_the_profile_along_the_track_and_double_click_resets(reports) -> None:
    folder = reports / 'review'
    page = folder / 'zoom_test.html'
    page.write_text((folder / 'report.html').read_text().replace('</body>', ZOOM))
    body = Elements(browser(page, '--dump-dom', '--window-size=1200,900')).select(
        'body', '', '')[0]
    out = json.loads(body['attrs']['data-zoom'])
    f = math.exp(-100 * 0.002)
    home, x, y = (np.array(out[k]) for k in ('home', 'x', 'y'))
    assert x[2] == pytest.approx(home[2] * f) and x[3] == pytest.approx(home[3])  # along only
    # about the pointer: the centre stays where it was
    assert x[0] + x[2] / 2 == pytest.approx(home[0] + home[2] / 2, abs=1e-3 * home[2])
    assert y[3] == pytest.approx(home[3] * f) and y[2] == pytest.approx(x[2])  # shift: depth
    assert np.allclose(out['reset'], home)
    assert np.allclose(np.array(out['mapZoom'])[2:], np.array(out['map'])[2:] * f)  # both axes
    labels = [float(t) for t in out['ticks']]  # the axis follows the zoom
    assert km(x[0] + x[2]) - 1e-3 <= min(labels) and max(labels) <= km(x[0]) + 1e-3


def test_fleet_report_map_limits_and_passes_in_the_browser(reports) -> None:
    folder = reports / 'fleet'
    dom = Elements(browser(folder / 'report.html', '--dump-dom'))
    defects = features(folder / 'fleet.geojson', 'defect')
    assert len(defects) == 2 and sum(d['properties']['new'] for d in defects) == 1
    assert len(dom.select('path', 'trace', 'zoom map')) == 1
    assert len(dom.select('path', 'section', 'zoom map')) == len(
        features(folder / 'fleet.geojson', 'section')) >= 5
    assert len(dom.select('path', 'mark', 'zoom map')) == 2
    assert len(dom.select('path', 'ring', 'zoom map')) == 1  # the new dip
    assert limit_classes(dom) == ['AL', 'AL', 'IAL', 'IAL', 'IL', 'IL']
    text = (folder / 'report.html').read_text()
    assert str(reports) not in text and 'passes/pass_01' in text  # relative to the database
    assert len(list(folder.glob('trends_*.png'))) == 1


WHERE = '<script>document.body.dataset.map = JSON.stringify(document.querySelector(' \
        "'svg.map').getBoundingClientRect());</script></body>"


def test_screenshot_of_the_review_shows_the_coloured_map(reports) -> None:
    from matplotlib.image import imread

    folder, size = reports / 'review', '--window-size=1280,1600'
    page = folder / 'where_test.html'
    page.write_text((folder / 'report.html').read_text().replace('</body>', WHERE))
    box = json.loads(Elements(browser(page, '--dump-dom', size)).select('body', '', '')[0]
                     ['attrs']['data-map'])
    shot = folder / 'shot.png'
    browser(folder / 'report.html', f'--screenshot={shot}', size, cwd=folder)
    rgb = imread(shot)[..., :3]
    assert rgb.shape[:2] == (1600, 1280) and rgb.std() > 0.05  # not blank
    assert box['bottom'] < 1600  # the map is in the screenshot
    drawn = rgb[int(box['top']):int(box['bottom']), int(box['left']):int(box['right'])]

    def pixels(colour: str, tol: float = 0.1) -> int:
        c = np.array([int(colour[i:i + 2], 16) / 255 for i in (1, 3, 5)])
        return int(np.sum(np.all(np.abs(drawn - c) < tol, axis=-1)))
    assert pixels('#2b8a3e') > 500  # sections below the alert range, in green
    assert pixels('#e0a800') + pixels('#c92a2a') > 100  # the dip's section: in or above
    assert pixels('#e8590c') > 30  # the IL dip's dot
