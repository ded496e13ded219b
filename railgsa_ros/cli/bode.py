"""``railgsa bode``: Bode diagram of the quarter vehicle (paper Fig. 10), its modes and zeros."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from railgsa_ros.vehicle import VehicleParams

DEFAULT_OUT = 'bode.png'


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``bode`` subcommand."""
    p = subparsers.add_parser(
        'bode', help='Bode diagram of sprung/unsprung acceleration per unit irregularity',
        description='Draw the Bode diagram of the car-body (sprung) and wheel (unsprung) '
                    'acceleration per metre of track irregularity (paper Fig. 10) and print the '
                    'modes (natural frequency, damping) and zeros.')
    p.add_argument('--out', default=DEFAULT_OUT, metavar='PATH',
                   help=f'image file; format from the suffix (default {DEFAULT_OUT})')
    p.add_argument('--vehicle', metavar='FILE',
                   help='vehicle YAML (vehicle: m_s m_us k_s k_us c); default the paper Table 1')
    p.add_argument('--fmin', type=float, default=0.1, metavar='HZ',
                   help='lowest frequency in Hz (default 0.1)')
    p.add_argument('--fmax', type=float, default=200.0, metavar='HZ',
                   help='highest frequency in Hz (default 200)')
    p.set_defaults(func=run)


def mode_table(params: VehicleParams) -> str:
    """Modes (natural frequency Hz, damping ratio, pole) and zeros of G_s and G_us as text."""
    import numpy as np

    from railgsa_ros.vehicle import modes, tf_polynomials, zeros_sprung

    lines = ['mode             f_n [Hz]   damping [-]   pole [rad/s]']
    for name, mode in zip(('car-body bounce', 'wheel hop'), modes(params), strict=True):
        pole = mode.pole
        lines.append(f'{name:<16} {mode.natural_frequency_hz:8.3f}   {mode.damping_ratio:11.4f}'
                     f'   {pole.real:.4g} +/- {abs(pole.imag):.4g}j')
    zeros_us = np.roots(tf_polynomials(params)[1][:3])  # drop the double zero at s = 0
    for name, zeros in (('G_s', zeros_sprung(params)), ('G_us', np.r_[0.0, 0.0, zeros_us])):
        text = ', '.join(_complex(z) for z in np.sort_complex(np.asarray(zeros, dtype=complex)))
        lines.append(f'zeros of {name:<5} [rad/s]: {text}')
    return '\n'.join(lines)


def _complex(z: complex) -> str:
    """A zero as text: real when its imaginary part is zero."""
    return f'{z.real:.4g}' if z.imag == 0 else f'{z.real:.4g}{z.imag:+.4g}j'


def plot_bode(params: VehicleParams, out: str | Path, fmin: float = 0.1,
              fmax: float = 200.0) -> Path:
    """Draw |G| (dB re 1 (m/s^2)/m) and phase (deg) of G_s and G_us over [fmin, fmax] Hz into
    ``out`` (written atomically; the format follows the suffix)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    import numpy as np

    from railgsa_ros.errors import ConfigError
    from railgsa_ros.fileio import atomic_output
    from railgsa_ros.vehicle import frequency_response, modes

    if not (0 < fmin < fmax) or not np.isfinite(fmax):
        raise ConfigError(f'--fmin/--fmax: need 0 < fmin < fmax, got {fmin} and {fmax}')
    out = Path(out)
    fig = Figure(figsize=(7.5, 6.0), layout='constrained')
    canvas = FigureCanvasAgg(fig)
    fmt = out.suffix.lstrip('.').lower()
    if fmt not in canvas.get_supported_filetypes():
        raise ConfigError(f'{out}: unsupported image format {out.suffix!r} '
                          f'(use one of {", ".join(sorted(canvas.get_supported_filetypes()))})')
    f_hz = np.logspace(np.log10(fmin), np.log10(fmax), 2000)
    mag_ax, phase_ax = fig.subplots(2, 1, sharex=True)
    for output, label in (('sprung', '$G_s$ (car body)'), ('unsprung', '$G_{us}$ (wheel)')):
        g = frequency_response(params, 2j * np.pi * f_hz, output)
        mag_ax.semilogx(f_hz, 20 * np.log10(np.abs(g)), label=label)
        phase_ax.semilogx(f_hz, np.degrees(np.unwrap(np.angle(g))), label=label)
    for mode in modes(params):
        for ax in (mag_ax, phase_ax):
            ax.axvline(mode.natural_frequency_hz, color='0.6', lw=0.8, ls='--')
    mag_ax.set_ylabel('magnitude [dB re 1 (m/s$^2$)/m]')
    phase_ax.set_ylabel('phase [deg]')
    phase_ax.set_xlabel('frequency [Hz]')
    mag_ax.set_title('Quarter vehicle: acceleration per unit track irregularity')
    mag_ax.legend()
    for ax in (mag_ax, phase_ax):
        ax.grid(True, which='both', alpha=0.3)
    with atomic_output(out, overwrite=True) as tmp:
        fig.savefig(tmp, format=fmt, dpi=120)
    return out


def run(args: argparse.Namespace) -> int:
    """Draw the diagram, then print the mode table."""
    from railgsa_ros.fileio import refuse_overlap
    from railgsa_ros.vehicle import VehicleParams, load_vehicle

    refuse_overlap(args.out, (args.vehicle,))
    params = load_vehicle(args.vehicle) if args.vehicle else VehicleParams()
    out = plot_bode(params, args.out, args.fmin, args.fmax)
    print(mode_table(params))
    print(f'wrote {out}')
    return 0
