"""MINPACK (scipy.optimize.least_squares, method='lm', analytic Jacobians by
sympy) on the 27 NIST StRD problems, from both starts: median wall time per
fit and correct significant digits, to compare with `cargo bench -p pkmcal-bench
--bench nist`. Run: python3 benchmarks/nist_scipy.py (needs scipy, sympy)."""

import pathlib, re, statistics, time
import numpy as np
import sympy as sp
from scipy.optimize import least_squares

DATA = pathlib.Path(__file__).resolve().parent.parent / "crates/pkmcal/tests/data/nist-strd"
MODELS = {
    "Misra1a": "b1*(1-exp(-b2*x))", "Chwirut2": "exp(-b1*x)/(b2+b3*x)",
    "Chwirut1": "exp(-b1*x)/(b2+b3*x)",
    "Lanczos3": "b1*exp(-b2*x) + b3*exp(-b4*x) + b5*exp(-b6*x)",
    "Gauss1": "b1*exp(-b2*x) + b3*exp(-(x-b4)**2/b5**2) + b6*exp(-(x-b7)**2/b8**2)",
    "Gauss2": "b1*exp(-b2*x) + b3*exp(-(x-b4)**2/b5**2) + b6*exp(-(x-b7)**2/b8**2)",
    "DanWood": "b1*x**b2", "Misra1b": "b1*(1-(1+b2*x/2)**(-2))",
    "Kirby2": "(b1 + b2*x + b3*x**2)/(1 + b4*x + b5*x**2)",
    "Hahn1": "(b1+b2*x+b3*x**2+b4*x**3)/(1+b5*x+b6*x**2+b7*x**3)",
    "Nelson": "b1 - b2*x*exp(-b3*x2)", "MGH17": "b1 + b2*exp(-x*b4) + b3*exp(-x*b5)",
    "Lanczos1": "b1*exp(-b2*x) + b3*exp(-b4*x) + b5*exp(-b6*x)",
    "Lanczos2": "b1*exp(-b2*x) + b3*exp(-b4*x) + b5*exp(-b6*x)",
    "Gauss3": "b1*exp(-b2*x) + b3*exp(-(x-b4)**2/b5**2) + b6*exp(-(x-b7)**2/b8**2)",
    "Misra1c": "b1*(1-(1+2*b2*x)**(-0.5))", "Misra1d": "b1*b2*x*((1+b2*x)**(-1))",
    "Roszman1": "b1 - b2*x - atan(b3/(x-b4))/pi",
    "ENSO": "b1 + b2*cos(2*pi*x/12) + b3*sin(2*pi*x/12) + b5*cos(2*pi*x/b4) + b6*sin(2*pi*x/b4) + b8*cos(2*pi*x/b7) + b9*sin(2*pi*x/b7)",
    "MGH09": "b1*(x**2+x*b2) / (x**2+x*b3+b4)",
    "Thurber": "(b1 + b2*x + b3*x**2 + b4*x**3)/(1 + b5*x + b6*x**2 + b7*x**3)",
    "BoxBOD": "b1*(1-exp(-b2*x))", "Rat42": "b1 / (1+exp(b2-b3*x))",
    "MGH10": "b1 * exp(b2/(x+b3))", "Eckerle4": "(b1/b2) * exp(-0.5*((x-b3)/b2)**2)",
    "Rat43": "b1 / ((1+exp(b2-b3*x))**(1/b4))", "Bennett5": "b1 * (b2+x)**(-1/b3)",
}


def load(name):
    lines = (DATA / f"{name}.dat").read_text().splitlines()
    rng = lambda key: [int(v) for v in re.findall(r"\d+", next(l for l in lines if key in l))[:2]]
    s0, s1 = rng("Starting Values")
    d0, d1 = rng("Data  ")
    rows = [l.split("=")[1].split() for l in lines[s0 - 1:s1]]
    starts = [np.array([float(r[0]) for r in rows]), np.array([float(r[1]) for r in rows])]
    cert = np.array([float(r[2]) for r in rows])
    rss = float(next(l for l in lines if l.startswith("Residual Sum of Squares")).split()[-1])
    data = np.array([[float(v) for v in l.split()] for l in lines[d0 - 1:d1]])
    return starts, cert, rss, data


def lre(est, cert):
    rel = abs((est - cert) / cert) if cert != 0 else abs(est)
    return 11.0 if rel == 0 else min(11.0, -np.log10(rel))


def main():
    print(f"{'problem':<9} {'start':>5} {'median ms':>10} {'digits':>7} {'nfev':>5}")
    for name, expr in MODELS.items():
        starts, cert, rss, data = load(name)
        n = len(cert)
        b = sp.symbols(f"b1:{n + 1}")
        x, x2 = sp.symbols("x x2")
        f = sp.sympify(expr, locals={"x": x, "x2": x2, **{f"b{i + 1}": b[i] for i in range(n)}})
        fun = sp.lambdify([b, x, x2], f, "numpy")
        grads = [sp.lambdify([b, x, x2], sp.diff(f, bi), "numpy") for bi in b]
        y = np.log(data[:, 0]) if name == "Nelson" else data[:, 0]
        xs = data[:, 1]
        x2s = data[:, 2] if data.shape[1] > 2 else np.zeros_like(xs)
        res = lambda p: fun(p, xs, x2s) - y
        jac = lambda p: np.column_stack([np.broadcast_to(g(p, xs, x2s), xs.shape) for g in grads])
        for k, x0 in enumerate(starts):
            times = []
            for _ in range(20):
                t = time.perf_counter()
                out = least_squares(res, x0, jac=jac, method="lm", ftol=1e-15, xtol=1e-15, gtol=1e-15, max_nfev=2000)
                times.append(time.perf_counter() - t)
            digits = min(min(lre(a, c) for a, c in zip(out.x, cert)), lre(2 * out.cost, rss))
            print(f"{name:<9} {k + 1:>5} {statistics.median(times) * 1e3:>10.3f} {digits:>7.1f} {out.nfev:>5}")


if __name__ == "__main__":
    main()
