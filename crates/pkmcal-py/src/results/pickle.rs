//! A calibration pickled in binary: its state without the arrays that grow
//! with the data as CBOR (every number kept as it is), and those arrays
//! (the Jacobian, residuals, σ, the poses and their errors) as raw bytes,
//! each cut into its eight byte planes, the planes that compress (the sign,
//! exponent and leading digits of floats; repeated lengths and flags)
//! deflated, as Blosc's shuffle filter does. Read back, the calibration is
//! the one pickled to the bit.

use crate::errors::{io_err, usage};
use pkmcal::Measurement;
use pkmcal::identify::ErrorVectors;
use pkmcal_io::record::CalibrationState;
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};

/// The format of the dict [`pack`] writes (1 was the JSON record's text).
pub const FORMAT: u32 = 2;

/// A plane is deflated when a sample of it shrinks below this share.
const WORTH_DEFLATING: f64 = 0.8;
/// The sample judged (bytes).
const SAMPLE: usize = 1 << 16;

/// Numbers kept as raw bytes: 8 bytes each (f64, i64 or u64 bit patterns).
#[derive(Default)]
struct Column(Vec<u64>);

impl Column {
    fn floats(v: &[f64]) -> Self {
        Column(v.iter().map(|x| x.to_bits()).collect())
    }
    fn floats_back(&self) -> Vec<f64> {
        self.0.iter().map(|b| f64::from_bits(*b)).collect()
    }
    /// The column as planes of bytes, byte `k` of every number in plane
    /// `k`, each plane deflated where that pays (zlib, through Python's
    /// module): `(planes, deflated)`.
    fn packed<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let n = self.0.len();
        let zlib = py.import("zlib")?;
        let mut planes = Vec::with_capacity(8);
        for k in 0..8 {
            let plane: Vec<u8> = self.0.iter().map(|v| (v >> (8 * k)) as u8).collect();
            let sample = &plane[..plane.len().min(SAMPLE)];
            let squeezed = zlib
                .call_method1("compress", (PyBytes::new(py, sample), 1))?
                .len()?;
            let deflate = n > 0 && (squeezed as f64) < WORTH_DEFLATING * sample.len() as f64;
            planes.push(if deflate {
                (
                    true,
                    zlib.call_method1("compress", (PyBytes::new(py, &plane), 1))?,
                )
            } else {
                (false, PyBytes::new(py, &plane).into_any())
            });
        }
        (n, planes).into_pyobject(py).map(|t| t.into_any())
    }
    fn unpacked(obj: &Bound<'_, PyAny>) -> PyResult<Self> {
        let py = obj.py();
        let zlib = py.import("zlib")?;
        let (n, planes): (usize, Vec<(bool, Bound<'_, PyAny>)>) = obj.extract()?;
        if planes.len() != 8 {
            return Err(bad("a column without its 8 planes"));
        }
        let mut out = vec![0u64; n];
        for (k, (deflated, bytes)) in planes.into_iter().enumerate() {
            let bytes = if deflated {
                zlib.call_method1("decompress", (bytes,))?
            } else {
                bytes
            };
            let bytes = bytes.cast::<PyBytes>()?.as_bytes();
            if bytes.len() != n {
                return Err(bad("a plane of another length"));
            }
            for (v, b) in out.iter_mut().zip(bytes) {
                *v |= u64::from(*b) << (8 * k);
            }
        }
        Ok(Column(out))
    }
}

fn bad(what: &str) -> PyErr {
    usage(format!(
        "a pickled pkmcal calibration that this version cannot read: {what}"
    ))
}

/// Rows of numbers of any lengths, some absent: their values one after the
/// other and each row's length (`u64::MAX` for an absent row).
#[derive(Default)]
struct Ragged {
    values: Vec<f64>,
    lens: Vec<u64>,
}

impl Ragged {
    fn push(&mut self, row: Option<&[f64]>) {
        match row {
            Some(r) => {
                self.values.extend_from_slice(r);
                self.lens.push(r.len() as u64);
            }
            None => self.lens.push(u64::MAX),
        }
    }
    fn rows(&self) -> PyResult<Vec<Option<Vec<f64>>>> {
        let mut at = 0usize;
        self.lens
            .iter()
            .map(|&l| {
                if l == u64::MAX {
                    return Ok(None);
                }
                let end = at
                    .checked_add(l as usize)
                    .filter(|&e| e <= self.values.len())
                    .ok_or_else(|| bad("rows longer than their values"))?;
                let r = self.values[at..end].to_vec();
                at = end;
                Ok(Some(r))
            })
            .collect()
    }
    fn put(&self, py: Python<'_>, d: &Bound<'_, PyDict>, name: &str) -> PyResult<()> {
        d.set_item(
            format!("{name}_values"),
            Column::floats(&self.values).packed(py)?,
        )?;
        d.set_item(
            format!("{name}_lens"),
            Column(self.lens.clone()).packed(py)?,
        )?;
        Ok(())
    }
    fn get(d: &Bound<'_, PyDict>, name: &str) -> PyResult<Self> {
        Ok(Ragged {
            values: Column::unpacked(&item(d, &format!("{name}_values"))?)?.floats_back(),
            lens: Column::unpacked(&item(d, &format!("{name}_lens"))?)?.0,
        })
    }
}

fn item<'py>(d: &Bound<'py, PyDict>, key: &str) -> PyResult<Bound<'py, PyAny>> {
    d.get_item(key)?.ok_or_else(|| bad(&format!("no `{key}`")))
}

fn ragged_of(rows: &[Vec<f64>]) -> Ragged {
    let mut r = Ragged::default();
    for row in rows {
        r.push(Some(row));
    }
    r
}

fn required(rows: Vec<Option<Vec<f64>>>) -> PyResult<Vec<Vec<f64>>> {
    rows.into_iter()
        .map(|r| r.ok_or_else(|| bad("an absent row where one is needed")))
        .collect()
}

/// The poses as columns.
#[derive(Default)]
struct Poses {
    target: Ragged,
    commands: Ragged,
    partner: Ragged,
    measured: Ragged,
    /// σ per reading, 0 where unknown (`sigma_known`).
    sigma: Ragged,
    sigma_known: Vec<u64>,
    /// 0: no origin; else 1 + (1 when a distance) + (2 when a line).
    origin: Vec<u64>,
    pose: Vec<u64>,
    line: Vec<u64>,
}

impl Poses {
    fn of(poses: &[Measurement]) -> Self {
        let mut p = Poses::default();
        for m in poses {
            p.target.push(m.target.as_deref());
            p.commands.push(Some(&m.commands));
            p.partner.push(m.partner.as_deref());
            p.measured.push(Some(&m.measured));
            let s: Vec<f64> = m.sigma.iter().map(|s| s.unwrap_or(0.0)).collect();
            p.sigma.push(Some(&s));
            p.sigma_known
                .extend(m.sigma.iter().map(|s| u64::from(s.is_some())));
            match m.origin {
                None => {
                    p.origin.push(0);
                    p.pose.push(0);
                    p.line.push(0);
                }
                Some(o) => {
                    p.origin
                        .push(1 + u64::from(o.distance) + 2 * u64::from(o.line.is_some()));
                    p.pose.push(o.pose as u64);
                    p.line.push(o.line.unwrap_or(0));
                }
            }
        }
        p
    }
    fn put(&self, py: Python<'_>, d: &Bound<'_, PyDict>) -> PyResult<()> {
        self.target.put(py, d, "target")?;
        self.commands.put(py, d, "commands")?;
        self.partner.put(py, d, "partner")?;
        self.measured.put(py, d, "measured")?;
        self.sigma.put(py, d, "sigma")?;
        for (name, v) in [
            ("sigma_known", &self.sigma_known),
            ("origin", &self.origin),
            ("pose", &self.pose),
            ("line", &self.line),
        ] {
            d.set_item(name, Column(v.clone()).packed(py)?)?;
        }
        Ok(())
    }
    fn get(d: &Bound<'_, PyDict>) -> PyResult<Vec<Measurement>> {
        let column =
            |name: &str| -> PyResult<Vec<u64>> { Ok(Column::unpacked(&item(d, name)?)?.0) };
        let (target, commands, partner, measured, sigma) = (
            Ragged::get(d, "target")?.rows()?,
            required(Ragged::get(d, "commands")?.rows()?)?,
            Ragged::get(d, "partner")?.rows()?,
            required(Ragged::get(d, "measured")?.rows()?)?,
            required(Ragged::get(d, "sigma")?.rows()?)?,
        );
        let (known, origin, pose, line) = (
            column("sigma_known")?,
            column("origin")?,
            column("pose")?,
            column("line")?,
        );
        let n = commands.len();
        if [
            target.len(),
            partner.len(),
            measured.len(),
            sigma.len(),
            origin.len(),
            pose.len(),
            line.len(),
        ]
        .iter()
        .any(|&l| l != n)
            || known.len() != sigma.iter().map(Vec::len).sum::<usize>()
        {
            return Err(bad("columns of different lengths"));
        }
        let mut known = known.into_iter();
        let mut out = Vec::with_capacity(n);
        for (i, ((((t, c), p), y), s)) in target
            .into_iter()
            .zip(commands)
            .zip(partner)
            .zip(measured)
            .zip(sigma)
            .enumerate()
        {
            let sigma = s
                .into_iter()
                .map(|v| (known.next() == Some(1)).then_some(v))
                .collect();
            let origin = match origin[i] {
                0 => None,
                o => Some(pkmcal::Origin {
                    pose: usize::try_from(pose[i]).map_err(|_| bad("a pose number"))?,
                    line: (o >= 3).then_some(line[i]),
                    distance: (o - 1) % 2 == 1,
                }),
            };
            out.push(Measurement {
                point: None,
                target: t,
                commands: c,
                partner: p,
                measured: y,
                sigma,
                origin,
            });
        }
        Ok(out)
    }
}

/// `state` as a dict of bytes (see the module's doc).
pub fn pack<'py>(py: Python<'py>, state: &CalibrationState) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let (study, cal) = (&state.study, &state.study.calibration);
    // The state without what is packed apart (copied without those).
    let light = CalibrationState {
        mechanism: state.mechanism.clone(),
        measurement: state.measurement.clone(),
        load: state.load.clone(),
        study: pkmcal::identify::Study {
            calibration: light_calibration(cal),
            accuracy: study.accuracy.clone(),
            before: vec![],
            after: vec![],
            poses: vec![],
            validation: study.validation.clone(),
            cross_validation: study.cross_validation.clone(),
        },
    };
    let mut bytes = vec![];
    pkmcal_io::record::encode(&light, &mut bytes).map_err(io_err)?;
    d.set_item("format", FORMAT)?;
    d.set_item("state", PyBytes::new(py, &bytes))?;
    d.set_item("residuals", Column::floats(&cal.residuals).packed(py)?)?;
    d.set_item("sigmas", Column::floats(&cal.sigmas).packed(py)?)?;
    d.set_item(
        "jacobian",
        Column::floats(cal.jacobian.as_slice()).packed(py)?,
    )?;
    d.set_item("jacobian_shape", cal.jacobian.shape())?;
    ragged_of(&study.before).put(py, &d, "before")?;
    ragged_of(&study.after).put(py, &d, "after")?;
    Poses::of(&study.poses).put(py, &d)?;
    Ok(d)
}

/// A calibration without its large vectors (packed apart).
fn light_calibration(c: &pkmcal::identify::Calibration) -> pkmcal::identify::Calibration {
    let mut c = c.clone();
    c.residuals = vec![];
    c.sigmas = vec![];
    c.jacobian = nalgebra::DMatrix::zeros(0, 0);
    c
}

/// What [`pack`] wrote, back.
pub fn unpack(d: &Bound<'_, PyDict>) -> PyResult<CalibrationState> {
    let format: u32 = item(d, "format")?.extract()?;
    if format != FORMAT {
        return Err(bad(&format!("format {format}")));
    }
    let mut state: CalibrationState =
        pkmcal_io::record::decode(item(d, "state")?.cast::<PyBytes>()?.as_bytes())
            .map_err(io_err)?;
    let cal = &mut state.study.calibration;
    cal.residuals = Column::unpacked(&item(d, "residuals")?)?.floats_back();
    cal.sigmas = Column::unpacked(&item(d, "sigmas")?)?.floats_back();
    let (r, c): (usize, usize) = item(d, "jacobian_shape")?.extract()?;
    let data = Column::unpacked(&item(d, "jacobian")?)?.floats_back();
    if r.checked_mul(c) != Some(data.len()) {
        return Err(bad("a Jacobian of another size"));
    }
    cal.jacobian = nalgebra::DMatrix::from_vec(r, c, data);
    let vectors =
        |name: &str| -> PyResult<ErrorVectors> { required(Ragged::get(d, name)?.rows()?) };
    state.study.before = vectors("before")?;
    state.study.after = vectors("after")?;
    state.study.poses = Poses::get(d)?;
    Ok(state)
}
