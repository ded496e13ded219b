"""Draw docs/figures/coach_nulls.png: what the shipped coach's car-body signals see of each
wavelength, with the null wavelengths (docs/vehicles.md).

Run from the repository root: ``python docs/figures/make_nulls.py [--speed MPS] [--out PNG]``.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
import numpy as np

from railgsa_ros.models import load_model
from railgsa_ros.models.coach import CoachModel, ImuPosition

ROOT = Path(__file__).resolve().parents[2]
COACH = ROOT / 'config' / 'vehicles' / 'coach.yaml'
D1, D2 = (3.0, 25.0), (25.0, 70.0)  # EN 13848 wavelength bands, m


def main() -> None:
    """Parse the options, draw and save the figure."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--speed', type=float, default=20.0, help='m/s (default 20)')
    parser.add_argument('--out', default=str(Path(__file__).with_name('coach_nulls.png')))
    args = parser.parse_args()
    shipped = load_model(COACH)
    assert isinstance(shipped, CoachModel)
    geometry = replace(shipped.geometry, imus=(ImuPosition('centre', 0.0),
                                               *shipped.geometry.imus))
    coach = CoachModel(shipped.params, geometry)
    waves = np.logspace(0, np.log10(200.0), 4000)
    h = np.abs(coach.track_response(coach.theta, args.speed / waves, args.speed))
    curves = [('accel_z:above_leading_bogie', 'vertical accel., IMU above the leading bogie'),
              ('accel_z', 'vertical accel., IMU at the car centre'),
              ('pitch_rate', 'pitch rate')]
    fig = Figure(figsize=(8.0, 7.5), layout='constrained')
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(curves), 1, sharex=True)
    for ax, (channel, label) in zip(axes, curves, strict=True):
        c = coach.channels.index(channel)
        ax.semilogx(waves, 20 * np.log10(h[c] / h[c].max() + 1e-12), 'k', lw=1.0)
        for wave in coach.null_wavelengths(channel):
            ax.axvline(wave, color='tab:red', lw=0.7, ls=':')
        for (lo, hi), name in ((D1, 'D1'), (D2, 'D2')):
            ax.axvspan(lo, hi, color='tab:blue' if name == 'D1' else 'tab:green', alpha=0.08)
            ax.text(np.sqrt(lo * hi), 2, name, ha='center', va='bottom', fontsize=8)
        ax.set_ylim(-60, 10)
        ax.set_ylabel('dB re max')
        ax.set_title(f'{label}: nulls (dotted) at '
                     + ', '.join(f'{w:.3g}' for w in coach.null_wavelengths(channel, 4.0))
                     + ' m ...', fontsize=9)
    axes[-1].set_xlabel('wavelength [m]')
    fig.suptitle(f'Manchester benchmark coach (config/vehicles/coach.yaml) at {args.speed:g} '
                 'm/s: track response in distance', fontsize=10)
    fig.savefig(args.out, dpi=110)
    print(f'wrote {args.out}')


if __name__ == '__main__':
    main()
