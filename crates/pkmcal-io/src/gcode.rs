//! `gcode`: rewrite the `G0`/`G1` moves of a G-code program through the
//! Cartesian pre-distortion ([`pkmcal::predistort`]), so that a controller
//! that runs its own (nominal) kinematics makes the calibrated machine reach
//! the programmed points.
//!
//! Tool axes map to words: `x y z` → `X Y Z`, `rx ry rz` → `A B C`, a planar
//! tool's `phi` → `C`; lengths in mm (`G21`, or inches after `G20`), angles
//! in degrees (the G-code convention). Supported: `G90`/`G91` (absolute or
//! relative), `G20`/`G21`, `M82`/`M83` and `G92 E` (extrusion, split with
//! the segments), comments `;…` and `(…)` at the end of a line. Refused with
//! the line, because firmwares read them differently or not at all: words
//! after a `(…)` comment, lines ended by a carriage return alone, checksums
//! (`*71`); and arcs (`G2`/`G3`), `G92` on a tool axis. `G28` (homing) forgets the position
//! until the next move gives every axis again.

use anyhow::{Context, Result};
use pkmcal::{CompensationOptions, Mechanism, Model, predistort};
use rayon::prelude::*;
use std::fmt::Write as _;
use std::path::PathBuf;

pub struct GcodeConfig {
    pub mechanism: Option<PathBuf>,
    pub params: PathBuf,
    pub controller: Option<PathBuf>,
    pub model: Model,
    /// The tool load (`--load`), one value per tool axis; empty for none.
    pub load: Vec<f64>,
    pub input: PathBuf,
    pub offset: Option<String>,
    pub max_segment: Option<f64>,
    pub out: PathBuf,
}

/// The G-code word of a tool axis.
fn word_of(axis: &str) -> Option<char> {
    match axis {
        "x" => Some('X'),
        "y" => Some('Y'),
        "z" => Some('Z'),
        "rx" => Some('A'),
        "ry" => Some('B'),
        "rz" | "phi" => Some('C'),
        _ => None,
    }
}

/// One line of the rewritten program, in order.
enum Item {
    /// A line kept as it is.
    Raw(String),
    /// `G28`: the position sent is unknown again.
    Reset,
    /// A pre-distorted piece of a move (index into the pieces).
    Piece(usize),
}

/// A piece of a move: its target and how to write it.
struct Piece {
    line_no: usize,
    piece: usize,
    pieces: usize,
    /// Tool coordinates (mm, rad).
    target: Vec<f64>,
    absolute: bool,
    scale: f64,
    g: String,
    e_text: Option<String>,
    others: Vec<String>,
    comment: String,
}

/// Most pieces one move is split into (`--max-segment`).
const MAX_PIECES: usize = 100_000;
/// Most pieces a whole program is split into (each is kept until the
/// program is written: about 200 bytes a piece).
const MAX_TOTAL_PIECES: usize = 2_000_000;

/// `G0`/`G1` (and their zero-padded forms).
fn is_linear(v: &str) -> bool {
    matches!(v, "0" | "00" | "1" | "01")
}

/// Digits written for lengths (mm: 0.1 µm) and angles (degrees).
const LENGTH_DECIMALS: usize = 4;
const ANGLE_DECIMALS: usize = 6;

/// One line split into its words (letter, number text) and its comment.
struct Line<'a> {
    words: Vec<(char, &'a str)>,
    comment: &'a str,
}

fn split(line: &str) -> Result<Line<'_>, String> {
    let (code, comment) = match line.find([';', '(']) {
        Some(i) => (&line[..i], &line[i..]),
        None => (line, ""),
    };
    // Words after a parenthesised comment are read differently by each
    // firmware (Klipper refuses the line, RepRapFirmware reads them, Marlin
    // only when built with PAREN_COMMENTS): refused, never guessed.
    if comment.starts_with('(') {
        let after = match comment.find(')') {
            Some(k) => &comment[k + 1..],
            None => "",
        };
        let after = after.split(';').next().unwrap_or("");
        if !after.trim().is_empty() {
            return Err(format!(
                "words after a (comment): `{}`; firmwares read them differently (Klipper refuses the line, RepRapFirmware reads them, Marlin only with PAREN_COMMENTS); move the comment to the end of the line",
                after.trim()
            ));
        }
    }
    let mut words = vec![];
    let b = code.as_bytes();
    let mut i = 0;
    while i < b.len() {
        let c = b[i] as char;
        if c.is_ascii_whitespace() {
            i += 1;
            continue;
        }
        if !c.is_ascii_alphabetic() {
            return Err(format!("unexpected `{c}`"));
        }
        let start = i + 1;
        let mut j = start;
        while j < b.len()
            && (b[j] == b'.'
                || b[j] == b'-'
                || b[j] == b'+'
                || b[j].is_ascii_digit()
                || b[j] == b' ')
        {
            if b[j] == b' ' && j > start && !code[start..j].trim().is_empty() {
                break;
            }
            j += 1;
        }
        words.push((c.to_ascii_uppercase(), code[start..j].trim()));
        i = j;
    }
    Ok(Line { words, comment })
}

pub fn run_gcode(run: &crate::Run<'_>, c: GcodeConfig) -> Result<()> {
    let mech = crate::io::read_description(run, c.mechanism.as_deref())?.mech;
    let spec = mech.spec();
    let real = crate::io::read_params(run, &c.params, &mech)?;
    let controller = crate::io::params_or_nominal(run, c.controller.as_deref(), &mech)?;
    let nx = spec.tool_axes.len();
    let force = crate::io::checked_load(c.load.clone(), &mech, &real)?;
    let opts = CompensationOptions {
        force,
        preload: vec![],
    };
    let words: Vec<char> = spec
        .tool_axes
        .iter()
        .map(|a| word_of(a).with_context(|| format!("tool axis `{a}` has no G-code word")))
        .collect::<Result<_>>()?;
    let angle: Vec<bool> = spec
        .tool_units
        .iter()
        .map(|u| *u == pkmcal::Unit::Radian)
        .collect();
    let offset = match &c.offset {
        Some(s) => {
            let v = crate::io::parse_list(s, "--offset")?;
            if v.len() != nx {
                return crate::output::usage(format!(
                    "--offset needs {nx} values (mm, and degrees for angles: {}), got {}",
                    spec.tool_axes.join(", "),
                    v.len()
                ));
            }
            v
        }
        None => vec![0.0; nx],
    };
    if let Some(m) = c.max_segment
        && !(m.is_finite() && m > 0.0)
    {
        return crate::output::usage("--max-segment must be a positive length in mm");
    }
    let text = run
        .files
        .read_to_string(&c.input, crate::output::InputKind::Data)
        .with_context(|| format!("cannot read G-code file {}", c.input.display()))?;
    let file = c.input.display();
    if let Some(k) = text
        .as_bytes()
        .windows(2)
        .position(|w| w[0] == b'\r' && w[1] != b'\n')
    {
        let line = text[..=k].matches('\n').count() + 1;
        return Err(anyhow::anyhow!(
            "{file}:{line}: a line ends in a carriage return alone (old Mac style), which firmwares read differently; convert the file to \\n or \\r\\n line ends"
        ));
    }
    // Programmed position in G-code units of each tool axis (None: unknown);
    // rotations not programmed stay at 0.
    let mut pos: Vec<Option<f64>> = (0..nx).map(|k| angle[k].then_some(0.0)).collect();
    // The pre-distorted position last sent (for relative moves).
    let mut sent_pos: Vec<Option<f64>> = pos.clone();
    let (mut absolute, mut inches, mut abs_e) = (true, false, true);
    let mut motion: Option<u32> = None;
    let mut e_pos = 0.0;
    // First pass: parse, follow the modes, cut moves into pieces (in order);
    // then every piece is pre-distorted in parallel; then the program is
    // written, relative coordinates from the pieces sent before.
    let mut items: Vec<Item> = Vec::with_capacity(text.lines().count());
    let mut pieces_out: Vec<Piece> = vec![];
    let mut moves = 0usize;
    for (n, raw) in text.lines().enumerate() {
        let line_no = n + 1;
        let here = |m: String| anyhow::anyhow!("{file}:{line_no}: {m}");
        let l = split(raw).map_err(|m| here(format!("{m}: not G-code")))?;
        let num = |v: &str, w: char| -> Result<f64> {
            let x: f64 = v
                .parse()
                .map_err(|_| here(format!("`{w}{v}` is not a number")))?;
            if !x.is_finite() {
                return Err(here(format!("`{w}{v}` is not finite")));
            }
            Ok(x)
        };
        let mut is_move = false;
        let mut g92 = false;
        for &(w, v) in &l.words {
            match (w, v) {
                ('G', v) if is_linear(v) => {
                    motion = Some(num(v, w)? as u32);
                    is_move = true;
                }
                ('G', "2" | "02" | "3" | "03") => {
                    return Err(here(
                        "arcs (G2/G3) are not rewritten; have the CAM or slicer write them as G1 segments".into(),
                    ));
                }
                ('G', "90") => absolute = true,
                ('G', "91") => absolute = false,
                ('G', "20") => inches = true,
                ('G', "21") => inches = false,
                ('G', "92") => g92 = true,
                ('G', "28") => {
                    for k in 0..nx {
                        if !angle[k] {
                            pos[k] = None;
                        }
                    }
                    items.push(Item::Reset);
                }
                ('M', "82") => abs_e = true,
                ('M', "83") => abs_e = false,
                _ => {}
            }
        }
        let has_axis = l.words.iter().any(|(w, _)| words.contains(w));
        if g92 {
            if has_axis {
                return Err(here(
                    "G92 on a tool axis shifts the coordinates; remove it or give the shift with --offset".into(),
                ));
            }
            if let Some((_, v)) = l.words.iter().find(|(w, _)| *w == 'E') {
                e_pos = num(v, 'E')?;
            }
            items.push(Item::Raw(raw.to_string()));
            continue;
        }
        let continues = !is_move
            && has_axis
            && motion.is_some()
            && l.words.iter().all(|(w, _)| *w != 'G' && *w != 'M');
        if !(is_move || continues) || !has_axis {
            if let Some((_, v)) = l.words.iter().find(|(w, _)| *w == 'E')
                && is_move
            {
                let e = num(v, 'E')?;
                e_pos = if abs_e { e } else { e_pos + e };
            }
            items.push(Item::Raw(raw.to_string()));
            continue;
        }
        // A move: the new programmed position.
        let scale = if inches { 25.4 } else { 1.0 };
        let from = pos.clone();
        for (k, w) in words.iter().enumerate() {
            if let Some((_, v)) = l.words.iter().find(|(x, _)| x == w) {
                let x = num(v, *w)? * if angle[k] { 1.0 } else { scale };
                pos[k] = Some(if absolute {
                    x
                } else {
                    pos[k].map_or(x, |p| p + x)
                });
                if !absolute && from[k].is_none() {
                    return Err(here(format!(
                        "relative move before the position of {} is known",
                        spec.tool_axes[k]
                    )));
                }
            }
        }
        if let Some(k) = pos.iter().position(Option::is_none) {
            return Err(here(format!(
                "a move before the position of `{}` is known (after the start or a G28); give every axis ({}) on the first move",
                spec.tool_axes[k],
                (0..nx)
                    .filter(|&k| !angle[k])
                    .map(|k| words[k].to_string())
                    .collect::<Vec<_>>()
                    .join(" ")
            )));
        }
        let to: Vec<f64> = pos.iter().map(|p| p.unwrap_or(0.0)).collect();
        let e_word = l.words.iter().find(|(w, _)| *w == 'E').map(|(_, v)| *v);
        let e_new = match e_word {
            Some(v) => {
                let e = num(v, 'E')?;
                Some(if abs_e { e } else { e_pos + e })
            }
            None => None,
        };
        // Segments: straight in programmed coordinates.
        let pieces = match (c.max_segment, from.iter().all(Option::is_some)) {
            (Some(max), true) => {
                let d: f64 = (0..nx)
                    .filter(|&k| !angle[k])
                    .map(|k| (to[k] - from[k].unwrap_or(0.0)).powi(2))
                    .sum::<f64>()
                    .sqrt();
                let n = (d / max).ceil();
                if n > MAX_PIECES as f64 {
                    return Err(here(format!(
                        "--max-segment {max} mm would split this {d:.3} mm move into more than {MAX_PIECES} pieces; use a larger --max-segment"
                    )));
                }
                (n as usize).max(1)
            }
            _ => 1,
        };
        if pieces_out.len() + pieces > MAX_TOTAL_PIECES {
            return Err(here(format!(
                "the program would be split into more than {MAX_TOTAL_PIECES} pieces in all; use a larger --max-segment"
            )));
        }
        let g = format!("G{}", motion.unwrap_or(1));
        // Words kept as they are (feed rate, other codes).
        let others: Vec<String> = l
            .words
            .iter()
            .filter(|(w, v)| !(words.contains(w) || *w == 'E' || (*w == 'G' && is_linear(v))))
            .map(|(w, v)| format!("{w}{v}"))
            .collect();
        for p in 1..=pieces {
            let f = p as f64 / pieces as f64;
            let point: Vec<f64> = (0..nx)
                .map(|k| match from[k] {
                    Some(a) if pieces > 1 => a + (to[k] - a) * f,
                    _ => to[k],
                })
                .collect();
            // Programmed (G-code units) to tool coordinates (mm, rad).
            let target: Vec<f64> = (0..nx)
                .map(|k| {
                    if angle[k] {
                        (point[k] + offset[k]).to_radians()
                    } else {
                        point[k] + offset[k]
                    }
                })
                .collect();
            let e_text = e_new.map(|en| {
                let e_here = e_pos + (en - e_pos) * f;
                let e_prev = e_pos + (en - e_pos) * (p - 1) as f64 / pieces as f64;
                let v = if abs_e { e_here } else { e_here - e_prev };
                format!(" E{v:.5}")
            });
            items.push(Item::Piece(pieces_out.len()));
            pieces_out.push(Piece {
                line_no,
                piece: p,
                pieces,
                target,
                absolute,
                scale,
                g: g.clone(),
                e_text,
                others: others.clone(),
                comment: if p == pieces {
                    l.comment.to_string()
                } else {
                    String::new()
                },
            });
        }
        if let Some(en) = e_new {
            e_pos = en;
        }
        moves += 1;
    }
    let results: Vec<pkmcal::Result<pkmcal::Predistortion>> = pieces_out
        .par_iter()
        .map(|pc| predistort(&mech, &controller, &real, &pc.target, c.model, &opts))
        .collect();
    let mut out = String::with_capacity(text.len() * 2);
    let (mut segments, mut worst) = (0usize, 0.0f64);
    for item in &items {
        let k_piece = match item {
            Item::Raw(r) => {
                out.push_str(r);
                out.push('\n');
                continue;
            }
            Item::Reset => {
                for k in 0..nx {
                    if !angle[k] {
                        sent_pos[k] = None;
                    }
                }
                continue;
            }
            Item::Piece(i) => *i,
        };
        let pc = &pieces_out[k_piece];
        let pd = match &results[k_piece] {
            Ok(pd) => pd,
            Err(e) => {
                let (line_no, p, pieces) = (pc.line_no, pc.piece, pc.pieces);
                return Err(if p < pieces {
                    anyhow::anyhow!(
                        "{file}:{line_no}: the straight move passes outside the reachable workspace (piece {p} of {pieces}): {e}; add an intermediate point or move around"
                    )
                } else {
                    anyhow::anyhow!("{file}:{line_no}: {e}")
                });
            }
        };
        let target = &pc.target;
        worst = worst.max(
            (0..nx)
                .filter(|&k| !angle[k])
                .map(|k| (pd.command_target[k] - target[k]).abs())
                .fold(0.0, f64::max),
        );
        let send: Vec<f64> = (0..nx)
            .map(|k| {
                if angle[k] {
                    pd.command_target[k].to_degrees() - offset[k]
                } else {
                    (pd.command_target[k] - offset[k]) / pc.scale
                }
            })
            .collect();
        let mut line = pc.g.clone();
        for k in 0..nx {
            // Every axis: the correction moves them all.
            let v = if pc.absolute {
                send[k]
            } else {
                send[k] - sent_pos[k].unwrap_or(send[k])
            };
            let decimals = if angle[k] {
                ANGLE_DECIMALS
            } else {
                LENGTH_DECIMALS
            };
            let _ = write!(line, " {}{:.*}", words[k], decimals, v);
            sent_pos[k] = Some(send[k]);
        }
        if let Some(e) = &pc.e_text {
            line.push_str(e);
        }
        for o in &pc.others {
            line.push(' ');
            line.push_str(o);
        }
        if !pc.comment.is_empty() {
            line.push(' ');
            line.push_str(&pc.comment);
        }
        out.push_str(&line);
        out.push('\n');
        segments += 1;
    }
    run.files.stage(&c.out, out.as_bytes())?;
    let (f, u) = pkmcal::Unit::Millimetre.readable(worst);
    crate::note!(
        "rewrote {moves} moves as {segments} pre-distorted moves (largest shift {:.3} {u}, {} model) -> {}",
        worst * f,
        c.model.name(),
        c.out.display()
    );
    Ok(())
}
