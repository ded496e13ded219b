"""Fused profile per line and the scatter of each pass around it, in SQL over ``profiles``.

Each pass p is modelled as u_p = (1 + g_p) f + e_p: f the line's true band-filtered profile, g_p
a relative gain (vehicle parameters, speed), e_p additive scatter with SD sigma_p. Both are
measured against the leave-one-out weighted mean of the other passes (window sums per cell, so
the pass does not judge itself): g_p by least squares and the residual variance V_p as
(1.4826 * MAD)^2 (robust against the few cells where the track changed between passes). Two
rounds: equal weights first, then weights 1 / V_p. The residual also holds the noise of the
other passes' mean, so V_p overstates sigma_p^2 (by half of it for 3 equal passes, twice for
2): ``pass_noise`` takes it out by solving the small linear system that links every V_p to all
sigma_q^2 (a three-cornered hat for n passes).

The fused profile is the inverse-variance weighted mean per cell; its SD is sqrt(1 / sum w),
inflated by the Birge ratio sqrt(chi2 / (n - 1)) where the passes disagree more than their
sigma_p says (a growing defect, a misaligned pass). With one pass there is no scatter to
measure: sigma_p is then ``PRIOR_SIGMA_M`` (the D1 accuracy target of the project) and flagged
by a NULL gain.
"""

from __future__ import annotations

import duckdb
import numpy as np

PRIOR_SIGMA_M = 3e-4  # D1 RMSE target for German-low profiles at 20-50 m/s (rail_domain.md)
MIN_SIGMA_M = 2e-5  # floor: the inversion is never better than this (keeps weights finite)
ROBUST_K = 4.0  # cells with |f| beyond ROBUST_K SD of f are left out of the gain fit (defects)
RCOND = 0.2  # singular values below this share of the largest are cut (two passes: see pass_noise)

_LOO = f"""
WITH p AS (
    SELECT pr.pass_id, pr.cell, pr.u_m, 1.0 / (s.sigma * s.sigma) AS w
    FROM profiles pr JOIN passes pa USING (pass_id) JOIN _sigma s USING (pass_id)
    WHERE pa.line = $line AND pa.track = $track AND pa.status = 'ok' AND pr.valid),
sums AS (
    SELECT *, sum(w * u_m) OVER (PARTITION BY cell) AS swu,
           sum(w) OVER (PARTITION BY cell) AS sw FROM p),
loo AS (
    SELECT pass_id, cell, u_m, (swu - w * u_m) / (sw - w) AS f FROM sums WHERE sw > w * 1.0000001),
spread AS (SELECT pass_id, stddev_pop(f) AS f_sd FROM loo GROUP BY pass_id),
gain AS (
    SELECT pass_id, sum(u_m * f) / sum(f * f) - 1.0 AS g
    FROM loo JOIN spread USING (pass_id) WHERE abs(f) < {ROBUST_K} * f_sd GROUP BY pass_id)
SELECT pass_id, g, 1.4826 * mad(u_m - (1.0 + g) * f) AS sigma
FROM loo JOIN gain USING (pass_id) GROUP BY pass_id, g
"""

_FUSED = """
WITH p AS (
    SELECT pr.cell, pr.u_m, 1.0 / (pa.noise_m * pa.noise_m) AS w
    FROM profiles pr JOIN passes pa USING (pass_id)
    WHERE pa.line = $line AND pa.track = $track AND pa.status = 'ok' AND pr.valid),
m AS (SELECT cell, sum(w * u_m) / sum(w) AS u_f, sum(w) AS sw, count(*) AS n FROM p GROUP BY cell)
SELECT $line, $track, cell, u_f,
       sqrt(1.0 / sw) * CASE WHEN n > 1 THEN greatest(1.0, sqrt(chi2 / (n - 1))) ELSE 1.0 END,
       n
FROM m JOIN (SELECT cell, sum(w * (u_m - u_f) * (u_m - u_f)) AS chi2
             FROM p JOIN m USING (cell) GROUP BY cell) USING (cell)
"""


def pass_noise(weights: np.ndarray, gains: np.ndarray, variances: np.ndarray) -> np.ndarray:
    """sigma_p (n,) m of n passes from their residual variances V (n,) m^2 measured against the
    leave-one-out mean of the others with weights w (n,) and gains g (n,):
    V_p = s_p + (1 + g_p)^2 sum_{q != p} w_q^2 s_q / (sum_{q != p} w_q)^2, solved for s by least
    squares and floored at MIN_SIGMA_M. Two passes see only the variance of their difference,
    s_1 + s_2: the system is singular and the minimum-norm solution gives each half of it.
    Assumes the passes cover the same cells (elsewhere the correction is approximate)."""
    w, g, v = (np.asarray(a, dtype=float) for a in (weights, gains, variances))
    coupling = w[None, :] ** 2 / (w.sum() - w)[:, None] ** 2
    np.fill_diagonal(coupling, 0.0)
    system = np.eye(w.size) + (1.0 + g)[:, None] ** 2 * coupling
    s = np.linalg.lstsq(system, v, rcond=RCOND)[0]
    return np.sqrt(np.maximum(s, MIN_SIGMA_M ** 2))


def pass_scatter(con: duckdb.DuckDBPyConnection, line: str, track: str) -> None:
    """Measure g_p and sigma_p of every 'ok' pass of the line (module docstring) and store them
    in passes.gain / passes.noise_m."""
    key = {'line': line, 'track': track}
    con.execute("""CREATE OR REPLACE TEMP TABLE _sigma AS SELECT pass_id, 1.0 AS sigma
                   FROM passes WHERE line = $line AND track = $track AND status = 'ok'""", key)
    for _ in range(2):
        con.execute('CREATE OR REPLACE TEMP TABLE _used AS SELECT * FROM _sigma')
        con.execute(f"""CREATE OR REPLACE TEMP TABLE _est AS {_LOO}""", key)
        con.execute(f"""CREATE OR REPLACE TEMP TABLE _sigma AS
                        SELECT pass_id, coalesce(greatest(e.sigma, {MIN_SIGMA_M}), {PRIOR_SIGMA_M})
                        AS sigma FROM _sigma LEFT JOIN _est e USING (pass_id)""")
    last = con.execute("""SELECT pass_id, 1.0 / (u.sigma * u.sigma) AS w, e.g,
                                 e.sigma * e.sigma AS v
                          FROM _used u JOIN _est e USING (pass_id)
                          ORDER BY pass_id""").fetchnumpy()
    if last['pass_id'].size >= 2:
        con.register('_noise', {'pass_id': last['pass_id'],
                                'sigma': pass_noise(last['w'], last['g'], last['v'])})
        con.execute('UPDATE _sigma SET sigma = n.sigma FROM _noise n '
                    'WHERE _sigma.pass_id = n.pass_id')
        con.unregister('_noise')
    con.execute("""UPDATE passes SET noise_m = s.sigma, gain = e.g
                   FROM _sigma s LEFT JOIN _est e USING (pass_id)
                   WHERE passes.pass_id = s.pass_id""")
    con.execute('DROP TABLE _sigma; DROP TABLE _est; DROP TABLE _used')


def fuse_line(con: duckdb.DuckDBPyConnection, line: str, track: str) -> None:
    """Replace the line's rows of ``fused`` by the weighted mean of its 'ok' passes."""
    key = {'line': line, 'track': track}
    con.execute('DELETE FROM fused WHERE line = $line AND track = $track', key)
    con.execute(f'INSERT INTO fused {_FUSED}', key)
