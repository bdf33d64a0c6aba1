//! The NIST StRD nonlinear regression problems (data in `tests/data/nist-strd`,
//! copied verbatim from the project's shared data): parser, models, and the
//! least-squares problem for `pkmcal::lm`.
#![allow(dead_code)]

use nalgebra::{Const, DMatrix, DVector, U1};
use num_dual::{DualNum, DualSVec64};
use pkmcal::lm::Problem;
use std::path::Path;

pub const NAMES: [&str; 27] = [
    "Misra1a", "Chwirut2", "Chwirut1", "Lanczos3", "Gauss1", "Gauss2", "DanWood", "Misra1b",
    "Kirby2", "Hahn1", "Nelson", "MGH17", "Lanczos1", "Lanczos2", "Gauss3", "Misra1c", "Misra1d",
    "Roszman1", "ENSO", "MGH09", "Thurber", "BoxBOD", "Rat42", "MGH10", "Eckerle4", "Rat43",
    "Bennett5",
];

pub struct Nist {
    pub name: String,
    pub starts: [Vec<f64>; 2],
    pub certified: Vec<f64>,
    pub std_dev: Vec<f64>,
    pub rss: f64,
    /// (y, x1, x2) rows.
    pub data: Vec<(f64, f64, f64)>,
    /// (y, x1) rows as exact-decimal double-doubles.
    data_dd: Vec<(Dd, Dd)>,
}

/// A decimal string (`2.5134E+00`) as a double-double, exact to ~1e-32.
fn parse_dd(t: &str) -> Dd {
    let (mant, exp) = match t.find(['E', 'e']) {
        Some(i) => (&t[..i], t[i + 1..].parse::<i32>().unwrap()),
        None => (t, 0),
    };
    let neg = mant.starts_with('-');
    let mant = mant.trim_start_matches(['-', '+']);
    let frac_digits = mant.find('.').map_or(0, |i| mant.len() - i - 1) as i32;
    let digits: String = mant.chars().filter(|c| *c != '.').collect();
    let m: u64 = digits.parse().unwrap();
    assert!(m < (1u64 << 53), "mantissa {t} too long");
    let p = exp - frac_digits;
    let v = if p >= 0 {
        Dd::prod(m as f64, 10f64.powi(p))
    } else {
        Dd(m as f64, 0.0).div_f(10f64.powi(-p))
    };
    if neg { Dd(-v.0, -v.1) } else { v }
}

fn line_range(text: &str, what: &str) -> (usize, usize) {
    let line = text.lines().find(|l| l.contains(what)).expect(what);
    let nums: Vec<usize> = line
        .split(|c: char| !c.is_ascii_digit())
        .filter(|s| !s.is_empty())
        .map(|s| s.parse().unwrap())
        .collect();
    (nums[0], nums[1])
}

pub fn load(name: &str) -> Nist {
    // Through `../pkmcal`: the same folder from the library's tests and from
    // the benchmarks' crate (crates/pkmcal-bench), which include this file.
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../pkmcal/tests/data/nist-strd")
        .join(format!("{name}.dat"));
    let text = std::fs::read_to_string(&path).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    let (s0, s1) = line_range(&text, "Starting Values");
    let (d0, d1) = line_range(&text, "Data  ");
    let (mut a, mut b, mut cert, mut sd) = (vec![], vec![], vec![], vec![]);
    for l in &lines[s0 - 1..s1] {
        let v: Vec<f64> = l
            .split('=')
            .nth(1)
            .unwrap()
            .split_whitespace()
            .map(|t| t.parse().unwrap())
            .collect();
        a.push(v[0]);
        b.push(v[1]);
        cert.push(v[2]);
        sd.push(v[3]);
    }
    let rss = lines
        .iter()
        .find(|l| l.starts_with("Residual Sum of Squares"))
        .unwrap()
        .split_whitespace()
        .last()
        .unwrap()
        .parse()
        .unwrap();
    let data_dd = lines[d0 - 1..d1]
        .iter()
        .map(|l| {
            let v: Vec<Dd> = l.split_whitespace().map(parse_dd).collect();
            (v[0], v[1])
        })
        .collect();
    let data = lines[d0 - 1..d1]
        .iter()
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|t| t.parse().unwrap()).collect();
            (v[0], v[1], v.get(2).copied().unwrap_or(0.0))
        })
        .collect();
    Nist {
        name: name.to_string(),
        starts: [a, b],
        certified: cert,
        std_dev: sd,
        rss,
        data,
        data_dd,
    }
}

/// The NIST model forms (Nelson: log y).
fn model<D: DualNum<Primitive = f64> + Copy>(name: &str, b: &[D], x: f64, x2: f64) -> D {
    let c = |v: f64| D::from(v);
    let pi = std::f64::consts::PI;
    match name {
        "Misra1a" | "BoxBOD" => b[0] * (c(1.0) - (-b[1] * x).exp()),
        "Chwirut1" | "Chwirut2" => (-b[0] * x).exp() / (b[1] + b[2] * x),
        "Lanczos1" | "Lanczos2" | "Lanczos3" => {
            b[0] * (-b[1] * x).exp() + b[2] * (-b[3] * x).exp() + b[4] * (-b[5] * x).exp()
        }
        "Gauss1" | "Gauss2" | "Gauss3" => {
            b[0] * (-b[1] * x).exp()
                + b[2] * (-(c(x) - b[3]).powi(2) / (b[4] * b[4])).exp()
                + b[5] * (-(c(x) - b[6]).powi(2) / (b[7] * b[7])).exp()
        }
        "DanWood" => b[0] * b[1].mul_add(c(x.ln()), c(0.0)).exp(),
        "Misra1b" => b[0] * (c(1.0) - (c(1.0) + b[1] * x / 2.0).powi(-2)),
        "Kirby2" => (b[0] + b[1] * x + b[2] * x * x) / (c(1.0) + b[3] * x + b[4] * x * x),
        "Hahn1" | "Thurber" => {
            (b[0] + b[1] * x + b[2] * x * x + b[3] * x * x * x)
                / (c(1.0) + b[4] * x + b[5] * x * x + b[6] * x * x * x)
        }
        "Nelson" => b[0] - b[1] * x * (-b[2] * x2).exp(),
        "MGH17" => b[0] + b[1] * (-b[3] * x).exp() + b[2] * (-b[4] * x).exp(),
        "Misra1c" => b[0] * (c(1.0) - (c(1.0) + b[1] * (2.0 * x)).powf(-0.5)),
        "Misra1d" => b[0] * b[1] * x / (c(1.0) + b[1] * x),
        "Roszman1" => b[0] - b[1] * x - (b[2] / (c(x) - b[3])).atan() / pi,
        "ENSO" => {
            let w = 2.0 * pi * x;
            b[0] + b[1] * (w / 12.0).cos()
                + b[2] * (w / 12.0).sin()
                + b[4] * (c(w) / b[3]).cos()
                + b[5] * (c(w) / b[3]).sin()
                + b[7] * (c(w) / b[6]).cos()
                + b[8] * (c(w) / b[6]).sin()
        }
        "MGH09" => b[0] * (b[1] * x + x * x) / (b[2] * x + b[3] + x * x),
        "Rat42" => b[0] / (c(1.0) + (b[1] - b[2] * x).exp()),
        "MGH10" => b[0] * (b[1] / (b[2] + x)).exp(),
        "Eckerle4" => b[0] / b[1] * (((c(x) - b[2]) / b[1]).powi(2) * -0.5).exp(),
        "Rat43" => b[0] / (c(1.0) + (b[1] - b[2] * x).exp()).powd(b[3].recip()),
        "Bennett5" => b[0] * (b[1] + x).powd(-b[2].recip()),
        other => panic!("unknown NIST problem {other}"),
    }
}

impl Nist {
    fn response(&self, y: f64) -> f64 {
        if self.name == "Nelson" { y.ln() } else { y }
    }

    /// Residual of observation `i`. Lanczos1's residuals (about 1e-13 on data
    /// of order 1) lie below the double-precision rounding of the model and of
    /// the decimal data themselves, so the Lanczos sums of exponentials are
    /// evaluated in double-double arithmetic on the exact decimal data; every
    /// other model in double precision.
    fn residual(&self, i: usize, b: &[f64], y: f64, x: f64, x2: f64) -> f64 {
        if self.name.starts_with("Lanczos") {
            let (yd, xd) = self.data_dd[i];
            let mut sum = Dd(0.0, 0.0);
            for k in 0..3 {
                let e = dd_exp(xd.mul_f(-b[2 * k + 1]));
                sum = sum.add(e.mul_f(b[2 * k]));
            }
            return sum.add(Dd(-yd.0, -yd.1)).0;
        }
        model(&self.name, b, x, x2) - self.response(y)
    }
}

/// A double-double number `hi + lo` (|lo| ≤ ulp(hi)/2).
#[derive(Clone, Copy)]
struct Dd(f64, f64);

impl Dd {
    fn two_sum(a: f64, b: f64) -> Dd {
        let s = a + b;
        let bb = s - a;
        Dd(s, (a - (s - bb)) + (b - bb))
    }
    fn prod(a: f64, b: f64) -> Dd {
        let p = a * b;
        Dd(p, a.mul_add(b, -p))
    }
    fn add(self, o: Dd) -> Dd {
        let s = Dd::two_sum(self.0, o.0);
        let t = s.1 + self.1 + o.1;
        Dd::two_sum(s.0, t)
    }
    fn mul(self, o: Dd) -> Dd {
        let p = Dd::prod(self.0, o.0);
        let lo = p.1 + (self.0 * o.1 + self.1 * o.0);
        Dd::two_sum(p.0, lo)
    }
    fn div_f(self, d: f64) -> Dd {
        let q1 = self.0 / d;
        let p = Dd::prod(q1, d);
        let rem = ((self.0 - p.0) - p.1) + self.1;
        Dd::two_sum(q1, rem / d)
    }
    fn mul_f(self, f: f64) -> Dd {
        self.mul(Dd(f, 0.0))
    }
}

/// exp in double-double: reduce by k·ln2 and 2⁻¹⁰, Taylor series, square back.
fn dd_exp(a: Dd) -> Dd {
    const LN2: Dd = Dd(std::f64::consts::LN_2, 2.319_046_813_846_299_6e-17);
    let k = (a.0 / LN2.0).round();
    let r = a.add(LN2.mul_f(-k));
    let r = Dd(r.0 / 1024.0, r.1 / 1024.0);
    let mut term = Dd(1.0, 0.0);
    let mut sum = Dd(1.0, 0.0);
    for n in 1..=14 {
        term = term.mul(r).div_f(n as f64);
        sum = sum.add(term);
    }
    for _ in 0..10 {
        sum = sum.mul(sum);
    }
    let scale = 2f64.powi(k as i32);
    Dd(sum.0 * scale, sum.1 * scale)
}

impl Problem for Nist {
    fn n_params(&self) -> usize {
        self.certified.len()
    }
    fn n_residuals(&self) -> usize {
        self.data.len()
    }
    fn evaluate(
        &self,
        b: &[f64],
        jacobian: bool,
    ) -> Result<(DVector<f64>, Option<DMatrix<f64>>), String> {
        let n = b.len();
        let m = self.data.len();
        let mut r = DVector::zeros(m);
        let mut j = jacobian.then(|| DMatrix::zeros(m, n));
        let bd: Vec<DualSVec64<9>> = b
            .iter()
            .enumerate()
            .map(|(i, &v)| DualSVec64::from_re(v).derivative(i))
            .collect();
        for (i, &(y, x, x2)) in self.data.iter().enumerate() {
            if let Some(j) = j.as_mut() {
                let f = model(&self.name, &bd, x, x2);
                r[i] = self.residual(i, b, y, x, x2);
                let e = f.eps.unwrap_generic(Const::<9>, U1);
                for k in 0..n {
                    j[(i, k)] = e[k];
                }
            } else {
                r[i] = self.residual(i, b, y, x, x2);
            }
        }
        Ok((r, j))
    }
}

/// Log relative error (number of correct significant digits), capped at 11.
pub fn lre(estimate: f64, certified: f64) -> f64 {
    if estimate == certified {
        return 11.0;
    }
    let rel = if certified != 0.0 {
        ((estimate - certified) / certified).abs()
    } else {
        estimate.abs()
    };
    (-rel.log10()).min(11.0)
}
