"""The Gough-Stewart calibration of `pkmcal calibrate` in numpy/scipy, to
compare speed on the same problem and check that both reach the same
least-squares minimum.

The problem: a platform of `examples/gough-stewart-6` (non-redundant, so the
exact model without load is the rigid one), every base and platform joint
centre and leg offset free (42 parameters), poses measured in the base frame
(`# frame: base`), each coordinate weighted by the sigma_<axis> columns of the
data file. Forward kinematics by Newton from the measured pose; the
identification Jacobian by implicit differentiation of the leg closure;
scipy.optimize.least_squares with MINPACK's Levenberg-Marquardt ('lm').
Leg lengths are command + offset (pkmcal's convention).

Run:
  python3 benchmarks/gough_stewart_scipy.py examples/gough-stewart-6/mechanism.toml data.csv [pkmcal-params.toml]
It prints the median wall time of the fit (and of the whole script's work:
reading included), and, given pkmcal's parameter file for the same data, the
largest difference of the identified parameters.
"""

import csv, statistics, sys, time, tomllib
import numpy as np
from scipy.optimize import least_squares

RUNS = 5


def rotation(a, b, c):
    sa, ca, sb, cb, sc, cc = np.sin(a), np.cos(a), np.sin(b), np.cos(b), np.sin(c), np.cos(c)
    rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
    ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    rz = np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]])
    drx = np.array([[0, 0, 0], [0, -sa, -ca], [0, ca, -sa]])
    dry = np.array([[-sb, 0, cb], [0, 0, 0], [-cb, 0, -sb]])
    drz = np.array([[-sc, -cc, 0], [cc, -sc, 0], [0, 0, 0]])
    return rz @ ry @ rx, [rz @ ry @ drx, rz @ dry @ rx, drz @ ry @ rx]


def closure(x, A, B):
    """Leg vectors, lengths, unit vectors and d(length)/d(pose) at pose x."""
    r, dr = rotation(*x[3:])
    w = x[:3] + B @ r.T - A
    length = np.linalg.norm(w, axis=1)
    u = w / length[:, None]
    jx = np.hstack([u, np.stack([np.einsum("ij,ij->i", u, B @ d.T) for d in dr], axis=1)])
    return r, length, u, jx


def forward(x0, A, B, legs):
    x = x0.copy()
    for _ in range(50):
        _, length, _, jx = closure(x, A, B)
        step = np.linalg.solve(jx, legs - length)
        x += step
        if np.max(np.abs(step)) < 1e-13:
            break
    return x


def main():
    mech = tomllib.load(open(sys.argv[1], "rb"))
    rows = [r for r in csv.DictReader(l for l in open(sys.argv[2]) if not l.startswith("#"))]
    n = len(mech["leg"])
    axes = ["x", "y", "z", "rx", "ry", "rz"]
    cmd = np.array([[float(r[f"L{i + 1}"]) for i in range(n)] for r in rows])
    meas = np.array([[float(r[a]) for a in axes] for r in rows])
    sig = np.array([[float(r[f"sigma_{a}"]) for a in axes] for r in rows])
    p0 = np.concatenate([np.ravel([l["base"] for l in mech["leg"]]),
                         np.ravel([l["platform"] for l in mech["leg"]]), np.zeros(n)])

    def unpack(p):
        return p[:3 * n].reshape(n, 3), p[3 * n:6 * n].reshape(n, 3), p[6 * n:]

    def residuals_and_jacobian(p):
        A, B, dl = unpack(p)
        res = np.empty(6 * len(rows))
        jac = np.zeros((6 * len(rows), 7 * n))
        for k in range(len(rows)):
            x = forward(meas[k], A, B, cmd[k] + dl)
            r, _, u, jx = closure(x, A, B)
            # g_i = |w_i| - (c_i + dL_i): dg/dA_i = -u_i, dg/dB_i = R^T u_i, dg/ddL_i = -1.
            jp = np.zeros((n, 7 * n))
            for i in range(n):
                jp[i, 3 * i:3 * i + 3] = -u[i]
                jp[i, 3 * n + 3 * i:3 * n + 3 * i + 3] = r.T @ u[i]
                jp[i, 6 * n + i] = -1.0
            dx = -np.linalg.solve(jx, jp)
            res[6 * k:6 * k + 6] = (x - meas[k]) / sig[k]
            jac[6 * k:6 * k + 6] = dx / sig[k][:, None]
        return res, jac

    cache = {}

    def fun(p):
        key = p.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = residuals_and_jacobian(p)
        return cache[key][0]

    def jac(p):
        fun(p)
        return cache[p.tobytes()][1]

    times = []
    for _ in range(RUNS):
        cache.clear()
        t = time.perf_counter()
        sol = least_squares(fun, p0, jac=jac, method="lm")
        times.append(time.perf_counter() - t)
    print(f"scipy least_squares (MINPACK lm): {len(rows)} poses, {7 * n} parameters, "
          f"{sol.nfev} evaluations, median {statistics.median(times) * 1e3:.1f} ms "
          f"(min {min(times) * 1e3:.1f}, max {max(times) * 1e3:.1f}); cost {sol.cost:.6e}")
    if len(sys.argv) > 3:
        theirs = {}
        for line in open(sys.argv[3]):
            if "=" in line and not line.startswith("#"):
                k, v = line.split("#")[0].split("=")
                theirs[k.strip().strip('"')] = float(v)
        names = [f"a{i + 1}{c}" for i in range(n) for c in "xyz"] + \
                [f"b{i + 1}{c}" for i in range(n) for c in "xyz"] + [f"dL{i + 1}" for i in range(n)]
        diff = max(abs(theirs[nm] - v) for nm, v in zip(names, sol.x))
        print(f"largest difference from pkmcal's parameters: {diff:.2e} mm")


if __name__ == "__main__":
    main()
