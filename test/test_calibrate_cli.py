"""railgsa calibrate's command line: the band it measures the discrepancy against."""

from __future__ import annotations

import numpy as np
import pytest

from railgsa_ros.cli.main import main
from railgsa_ros.track import save_csv
from railgsa_ros.uncertainty import offline_bands
from railgsa_ros.vehicle import VehicleParams

NOMINAL = VehicleParams()


def test_cli_measures_the_discrepancy_with_the_bands_params_file(short_bag, tmp_path, capsys,
                                                                  monkeypatch):
    """--uncertainty-params: the band the discrepancy is measured against has the file's
    sensor terms (here the ADXL355-like 20 ppm clock), so d is beyond the terms the bands will
    run with; a misspelt key is refused with one line naming it and the file. (The fit and the
    discrepancy are replaced and the band recorded: this checks the wiring; the estimator's
    tests are above.)"""
    import railgsa_ros.calibrate as core
    from railgsa_ros.calibrate import Calibration
    import railgsa_ros.uncertainty as uncertainty

    seen = {}

    def fit(*args, **kwargs):
        return Calibration(('k_s',), np.array([NOMINAL.k_s]), np.eye(1), NOMINAL.as_array(),
                           0.0, 0.0, 1.0, 1.0, 100)

    def bands(*args, config, **kwargs):
        seen['config'] = config
        return offline_bands(*args, config=config, **kwargs)

    monkeypatch.setattr(core, 'calibrate', fit)
    monkeypatch.setattr(core, 'discrepancy_std', lambda *args: 0.0)  # 75 m: no stretch left
    monkeypatch.setattr(uncertainty, 'offline_bands', bands)
    ref = tmp_path / 'ref.csv'
    save_csv(ref, np.arange(0.0, 70.0, 0.25), np.zeros(280))
    params = tmp_path / 'params.yaml'
    args = ['calibrate', str(short_bag), '--reference', str(ref), '--uncertainty-params',
            str(params), '--out-vehicle', str(tmp_path / 'v.yaml'),
            '--out-uncertainty', str(tmp_path / 'u.yaml')]
    params.write_text('uncertainty_node:\n  ros__parameters:\n    clock_std_ppm: 20.0\n')
    assert main(args) == 0
    assert seen['config'].clock_std_ppm == 20.0  # and the bag's inversion (its median rate):
    assert seen['config'].inversion.rate_hz == pytest.approx(500.0, rel=1e-3)
    params.write_text('uncertainty_node:\n  ros__parameters:\n    clock_std_pmm: 20.0\n')
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert 'clock_std_pmm' in err and str(params) in err and '\n' not in err
