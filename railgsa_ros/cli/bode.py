"""``railgsa bode``: Bode diagram of a vehicle, its modes (and the quarter car's zeros).

The quarter car: the paper's Fig. 10 (sprung and unsprung acceleration). A coach file: per
channel, each wheelset's response alone and the track response (the four summed with their
delays at ``--speed``), the null wavelengths on a wavelength axis, and the mode table."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from railgsa_ros.models.coach import CoachModel
    from railgsa_ros.vehicle import VehicleParams

DEFAULT_OUT = 'bode.png'


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``bode`` subcommand."""
    p = subparsers.add_parser(
        'bode', help='Bode diagram of a vehicle\'s responses per unit irregularity, its modes',
        description='Draw the Bode diagram of the car-body (sprung) and wheel (unsprung) '
                    'acceleration per metre of track irregularity (paper Fig. 10) and print the '
                    'modes (natural frequency, damping) and zeros; for a coach file, each '
                    'channel per wheelset and summed with the wheelsets\' delays at --speed, '
                    'with its null wavelengths.')
    p.add_argument('--out', default=DEFAULT_OUT, metavar='PATH',
                   help=f'image file; format from the suffix (default {DEFAULT_OUT})')
    p.add_argument('--vehicle', metavar='FILE',
                   help='vehicle YAML: a quarter car (vehicle: m_s m_us k_s k_us c) or a coach '
                        '(model: coach); default the paper Table 1')
    p.add_argument('--speed', type=float, default=20.0, metavar='MPS',
                   help='speed for a coach\'s wheelset delays in m/s (default 20)')
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


def _figure(out: Path, fmin: float, fmax: float, height: float) -> tuple[Figure, str]:
    """A figure to be saved as ``out`` and its format; ConfigError for a bad range or suffix."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    import numpy as np

    from railgsa_ros.errors import ConfigError

    if not (0 < fmin < fmax) or not np.isfinite(fmax):
        raise ConfigError(f'--fmin/--fmax: need 0 < fmin < fmax, got {fmin} and {fmax}')
    fig = Figure(figsize=(7.5, height), layout='constrained')
    canvas = FigureCanvasAgg(fig)
    fmt = out.suffix.lstrip('.').lower()
    if fmt not in canvas.get_supported_filetypes():
        raise ConfigError(f'{out}: unsupported image format {out.suffix!r} '
                          f'(use one of {", ".join(sorted(canvas.get_supported_filetypes()))})')
    return fig, fmt


def _save(fig: Figure, out: Path, fmt: str) -> Path:
    """Write the figure atomically; grids on every axis."""
    from railgsa_ros.fileio import atomic_output

    for ax in fig.axes:
        ax.grid(True, which='both', alpha=0.3)
    with atomic_output(out, overwrite=True) as tmp:
        fig.savefig(tmp, format=fmt, dpi=120)
    return out


def plot_bode(params: VehicleParams, out: str | Path, fmin: float = 0.1,
              fmax: float = 200.0) -> Path:
    """Draw |G| (dB re 1 (m/s^2)/m) and phase (deg) of G_s and G_us over [fmin, fmax] Hz into
    ``out`` (written atomically; the format follows the suffix)."""
    import numpy as np

    from railgsa_ros.vehicle import frequency_response, modes

    out = Path(out)
    fig, fmt = _figure(out, fmin, fmax, 6.0)
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
    return _save(fig, out, fmt)


UNITS = {'pitch_rate': '(rad/s)/m'}  # channel -> unit of its response; accelerations (m/s^2)/m


def plot_coach_bode(model: CoachModel, out: str | Path, speed_mps: float, fmin: float = 0.1,
                    fmax: float = 200.0) -> Path:
    """Per channel: |H| (dB re 1 unit/m) of each wheelset alone (thin) and of the track response
    at ``speed_mps`` (thick), null wavelengths down to 1 m dotted, wavelength (m) on the top
    axis; last: the track responses' phase (deg). Written atomically to ``out``."""
    import numpy as np

    from railgsa_ros.cli.simulate import check_positive

    check_positive(speed=speed_mps)
    out = Path(out)
    channels = model.channels
    fig, fmt = _figure(out, fmin, fmax, 2.4 * len(channels) + 2.4)
    axes = fig.subplots(len(channels) + 1, 1, sharex=True)
    f_hz = np.logspace(np.log10(fmin), np.log10(fmax), 3000)
    h = model.frequency_response(model.theta, 2j * np.pi * f_hz)
    track = model.track_response(model.theta, f_hz, speed_mps)
    tiny = 1e-300  # |H| = 0 exactly at a null: -inf dB would break the axis limits

    def invert(x: np.ndarray) -> np.ndarray:
        """Frequency (Hz) <-> wavelength (m) at the speed (matplotlib also passes 0)."""
        with np.errstate(divide='ignore'):
            return speed_mps / np.asarray(x, dtype=float)

    for c, (ax, channel) in enumerate(zip(axes, channels, strict=False)):
        for w in range(h.shape[-2]):
            ax.semilogx(f_hz, 20 * np.log10(np.abs(h[c, w]) + tiny), lw=0.7,
                        label=f'wheelset {w + 1} alone')
        ax.semilogx(f_hz, 20 * np.log10(np.abs(track[c]) + tiny), 'k', lw=1.5,
                    label=f'all four at {speed_mps:g} m/s')
        peak = 20 * np.log10(np.abs(track[c]).max())
        ax.set_ylim(peak - 80, peak + 15)
        for wave in model.null_wavelengths(channel, max(1.0, speed_mps / fmax)):
            ax.axvline(speed_mps / wave, color='0.5', lw=0.6, ls=':')
        ax.set_ylabel(f'{channel}\n[dB re 1 {UNITS.get(channel, "(m/s$^2$)/m")}]')
        top = ax.secondary_xaxis('top', functions=(invert, invert))
        top.set_xlabel('wavelength [m]' if c == 0 else '')
        axes[-1].semilogx(f_hz, np.degrees(np.unwrap(np.angle(track[c]))), label=channel)
    axes[0].legend(fontsize=7, ncol=3)
    axes[-1].set_ylabel('phase, all four [deg]')
    axes[-1].set_xlabel('frequency [Hz]')
    axes[-1].legend(fontsize=7)
    return _save(fig, out, fmt)


def model_table(model: CoachModel, speed_mps: float) -> str:
    """Modes (natural frequency Hz, damping ratio, what moves), wheelset offsets and each
    channel's null wavelengths (m, down to 1 m) as text."""
    lines = ['mode                                f_n [Hz]   damping [-]']
    lines += [f'{m.description:<35} {m.f_hz:8.3f}   {m.zeta:11.4f}' for m in model.modes()]
    offsets = ', '.join(f'{d:g}' for d in model.wheel_offsets_m)
    lines.append(f'wheelsets behind the reference [m]: {offsets} '
                 f'(delays at {speed_mps:g} m/s [s]: '
                 f'{", ".join(f"{d / speed_mps:.4g}" for d in model.wheel_offsets_m)})')
    for channel in model.channels:
        waves = ', '.join(f'{w:.3g}' for w in model.null_wavelengths(channel))
        lines.append(f'nulls of {channel} [m]: {waves}')
    return '\n'.join(lines)


def run(args: argparse.Namespace) -> int:
    """Draw the diagram, then print the mode table."""
    from railgsa_ros.fileio import refuse_overlap
    from railgsa_ros.models import load_model

    refuse_overlap(args.out, (args.vehicle,))
    model: Any = load_model(args.vehicle) if args.vehicle else None
    if model is not None and model.kind == 'coach':
        out = plot_coach_bode(model, args.out, args.speed, args.fmin, args.fmax)
        print(model_table(model, args.speed))
    else:
        from railgsa_ros.vehicle import VehicleParams

        params = VehicleParams() if model is None else model.params
        out = plot_bode(params, args.out, args.fmin, args.fmax)
        print(mode_table(params))
    print(f'wrote {out}')
    return 0
