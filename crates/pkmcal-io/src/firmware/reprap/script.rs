//! RepRapFirmware's G-code language, as far as a configuration's settings
//! depend on it, read as the firmware runs a file (its `StringParser`,
//! `ExpressionParser` and `GCodeMachineState`, RepRapFirmware 3.5):
//!
//! - a line: an optional line number `N…` and then a checksum `*…` (only
//!   after a line number, as the firmware reads it; a wrong one is refused:
//!   the firmware skips the line), a `;` comment, the indentation (a space
//!   counts 1, a tab moves to the next multiple of 4);
//! - several commands on one line: a `G` or `M` outside quotes and braces
//!   starts the next;
//! - parameters as the firmware's `Seen` finds them: the first occurrence of
//!   a letter, in either case, an `E` right after a digit being an exponent;
//!   numbers as its `SafeStrtod` reads them; `{…}` expressions;
//! - expressions: numbers, strings, `true`/`false`/`pi`/`iterations`/`line`,
//!   `global.`, `var.` and `param.` variables, `! - + #`, `* / + - = == !=
//!   < <= > >= & && | || ^ ?:` with the firmware's priorities, arrays
//!   `{a, b}` and the functions of pure arithmetic (`abs`, `sqrt`, `sin`, …,
//!   `exists`); integer arithmetic on integers, 32-bit floats otherwise;
//! - blocks: `if`/`elif`/`else`, `while` (with `iterations`), `break`,
//!   `continue`, `abort`, `var`/`global`/`set`, `echo`, `skip`, by
//!   indentation exactly as the firmware opens and closes them (a comment at
//!   the start of a line closes blocks too, and a loop that runs to the end
//!   of the file is closed there);
//! - macros: `M98 P"file"` (with its parameters as `param.X`) and `M501`
//!   run the file in place (`M501` inside `M501` is ignored, as the firmware
//!   ignores it), `M99` returns.
//!
//! What the files cannot tell (the firmware's object model, a function
//! pkmcal does not evaluate) is carried as unknown with why: an error only
//! where the settings depend on it. A block whose condition is unknown is
//! followed when none of its lines sets what the caller reads (its
//! variables become unknown), and refused by name otherwise: a value is
//! never read from a branch the firmware might not run. Every recursion and
//! loop is bounded: expressions ([`MAX_EXPRESSION_DEPTH`]), macros
//! ([`MAX_MACRO_DEPTH`], the firmware's own `MaxStackDepth`), loops
//! ([`MAX_ITERATIONS`]) and lines run ([`MAX_LINES_RUN`]).

use crate::error::{Error, Result};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// The most nested operators and brackets an expression may hold: the
/// firmware's own stack check stops it well before (a line holds at most
/// 255 characters there).
pub const MAX_EXPRESSION_DEPTH: usize = 64;
/// The most files open at once, the configuration included: the firmware's
/// `MaxStackDepth`.
pub const MAX_MACRO_DEPTH: usize = 10;
/// The most iterations of `while` loops in one reading, all loops together.
pub const MAX_ITERATIONS: u64 = 100_000;
/// The most lines run in one reading (loops and macros counted each time).
pub const MAX_LINES_RUN: u64 = 1_000_000;

/// A value of an expression.
#[derive(Debug, Clone, PartialEq)]
#[doc(hidden)] // public for the integration tests only
pub enum Value {
    /// A 32-bit integer (the firmware's `int32`).
    Int(i32),
    /// A float, held at the firmware's precision (32 bits).
    Float(f64),
    Bool(bool),
    Str(String),
    Array(Vec<Value>),
    Null,
}

impl Value {
    #[doc(hidden)] // public for the integration tests only
    pub fn float(x: f64) -> Value {
        Value::Float(x as f32 as f64)
    }

    fn kind(&self) -> &'static str {
        match self {
            Value::Int(_) | Value::Float(_) => "a number",
            Value::Bool(_) => "a Boolean",
            Value::Str(_) => "a string",
            Value::Array(_) => "an array",
            Value::Null => "null",
        }
    }

    fn number(&self) -> Option<f64> {
        match self {
            Value::Int(i) => Some(f64::from(*i)),
            Value::Float(f) => Some(*f),
            _ => None,
        }
    }
}

/// An expression's value, or why it is not known here (its text says why,
/// and what to do).
#[doc(hidden)] // public for the integration tests only
pub type Eval = std::result::Result<Value, String>;

/// A variable: its value (or why it is unknown), and whether it certainly
/// exists (not when it was set in a block whose condition is unknown).
#[derive(Debug, Clone)]
#[doc(hidden)] // public for the integration tests only
pub struct Slot {
    value: Eval,
    certain: bool,
}

/// A local variable (`var`): its name, value and the block nesting it was
/// declared at.
#[derive(Debug, Clone)]
#[doc(hidden)] // public for the integration tests only
pub struct Local {
    name: String,
    slot: Slot,
    nesting: usize,
}

/// What the expressions of a line can read.
#[doc(hidden)] // public for the integration tests only
pub struct Scope<'a> {
    #[doc(hidden)] // public for the integration tests only
    pub globals: &'a HashMap<String, Slot>,
    #[doc(hidden)] // public for the integration tests only
    pub locals: &'a [Local],
    #[doc(hidden)] // public for the integration tests only
    pub params: &'a HashMap<char, Eval>,
    /// The innermost loop's iterations, if in a loop.
    #[doc(hidden)] // public for the integration tests only
    pub iterations: Option<u32>,
    /// The line's number.
    #[doc(hidden)] // public for the integration tests only
    pub line: usize,
}

/// An expression parser over one text, as the firmware's
/// `ExpressionParser::ParseInternal`: binary operators by priority, unary
/// ones above them; with `evaluate` false (the operand a `&&`, `||` or `?:`
/// does not take), parsed only.
struct Parser<'a, 's> {
    s: &'s [u8],
    i: usize,
    depth: usize,
    scope: &'a Scope<'a>,
}

const OPERATORS: &[u8] = b"?^&|!=<>+-*/";
const PRIORITIES: [u8; 12] = [1, 2, 3, 3, 4, 4, 4, 4, 5, 5, 6, 6];
const UNARY_PRIORITY: u8 = 10;

impl Parser<'_, '_> {
    fn peek(&self) -> u8 {
        self.s.get(self.i).copied().unwrap_or(0)
    }

    fn ws(&mut self) -> u8 {
        while matches!(self.peek(), b' ' | b'\t') {
            self.i += 1;
        }
        self.peek()
    }

    fn text(&self) -> String {
        String::from_utf8_lossy(self.s).into_owned()
    }

    fn deeper(&mut self) -> std::result::Result<(), String> {
        self.depth += 1;
        if self.depth > MAX_EXPRESSION_DEPTH {
            return Err(format!(
                "`{}` nests more than {MAX_EXPRESSION_DEPTH} brackets or operators deep (the firmware's own stack allows fewer); simplify the expression",
                short(&self.text(), 60)
            ));
        }
        Ok(())
    }

    /// The whole text as one expression.
    fn all(mut self) -> Eval {
        let v = self.internal(true, 0)?;
        if self.ws() != 0 {
            return Err(format!(
                "`{}`: unexpected `{}` after the expression",
                self.text(),
                self.peek() as char
            ));
        }
        Ok(v)
    }

    fn internal(&mut self, evaluate: bool, priority: u8) -> Eval {
        self.deeper()?;
        let mut v = self.primary(evaluate)?;
        loop {
            let c = self.ws();
            let Some(index) = OPERATORS.iter().position(|&o| o == c) else {
                break;
            };
            let prio = PRIORITIES[index];
            if prio <= priority {
                break;
            }
            self.i += 1;
            let mut op = c;
            let mut invert = false;
            if op == b'!' {
                if self.peek() != b'=' {
                    return Err(format!("`{}`: expected `=` after `!`", self.text()));
                }
                self.i += 1;
                invert = true;
                op = b'=';
            } else if matches!(op, b'<' | b'>') && self.peek() == b'=' {
                self.i += 1;
                invert = true;
                op = if op == b'<' { b'>' } else { b'<' };
            }
            if matches!(op, b'=' | b'&' | b'|') && self.peek() == op {
                self.i += 1;
            }
            match op {
                b'&' | b'|' => {
                    let a = if evaluate { truth(&v)? } else { false };
                    let takes = evaluate && (if op == b'&' { a } else { !a });
                    let w = self.internal(takes, prio)?;
                    v = if !evaluate {
                        Value::Null
                    } else if takes {
                        Value::Bool(truth(&w)?)
                    } else {
                        Value::Bool(a)
                    };
                }
                b'?' => {
                    let b = if evaluate { truth(&v)? } else { false };
                    let first = self.internal(evaluate && b, prio)?;
                    if self.ws() != b':' {
                        return Err(format!("`{}`: expected `:` after `?`", self.text()));
                    }
                    self.i += 1;
                    let second = self.internal(evaluate && !b, prio - 1)?;
                    self.depth -= 1;
                    return Ok(if !evaluate {
                        Value::Null
                    } else if b {
                        first
                    } else {
                        second
                    });
                }
                _ => {
                    let w = self.internal(evaluate, prio)?;
                    v = if evaluate {
                        binary(op, invert, v, w).map_err(|e| format!("`{}`: {e}", self.text()))?
                    } else {
                        Value::Null
                    };
                }
            }
        }
        self.depth -= 1;
        Ok(v)
    }

    fn primary(&mut self, evaluate: bool) -> Eval {
        let c = self.ws();
        match c {
            b'"' => self.string(),
            b'-' | b'+' | b'!' | b'#' => {
                self.i += 1;
                let v = self.internal(evaluate, UNARY_PRIORITY)?;
                if !evaluate {
                    return Ok(Value::Null);
                }
                match (c, v) {
                    (b'-', Value::Int(i)) => Ok(Value::Int(i.wrapping_neg())),
                    (b'-', Value::Float(f)) => Ok(Value::Float(-f)),
                    (b'+', v @ (Value::Int(_) | Value::Float(_))) => Ok(v),
                    (b'!', v) => Ok(Value::Bool(!truth(&v)?)),
                    (b'#', Value::Str(s)) => Ok(Value::Int(s.len() as i32)),
                    (b'#', Value::Array(a)) => Ok(Value::Int(a.len() as i32)),
                    (c, v) => Err(format!(
                        "`{}`: `{}` applied to {}",
                        self.text(),
                        c as char,
                        v.kind()
                    )),
                }
            }
            b'{' | b'(' => {
                self.i += 1;
                let close = if c == b'{' { b'}' } else { b')' };
                let first = self.internal(evaluate, 0)?;
                let v = if c == b'{' && self.ws() == b',' {
                    let mut items = vec![first];
                    while self.ws() == b',' {
                        self.i += 1;
                        if self.ws() == b'}' {
                            break;
                        }
                        items.push(self.internal(evaluate, 0)?);
                    }
                    Value::Array(items)
                } else {
                    first
                };
                if self.ws() != close {
                    return Err(format!(
                        "`{}`: a `{}` is not closed",
                        self.text(),
                        c as char
                    ));
                }
                self.i += 1;
                Ok(v)
            }
            b'0'..=b'9' | b'.' => self.number(),
            c if c.is_ascii_alphabetic() => self.identifier(evaluate),
            0 => Err(format!("`{}`: an expression ends early", self.text())),
            c => Err(format!(
                "`{}`: `{}` does not start an expression",
                self.text(),
                c as char
            )),
        }
    }

    fn string(&mut self) -> Eval {
        self.i += 1;
        let mut out = String::new();
        loop {
            let c = self.peek();
            if c == 0 {
                return Err(format!("`{}`: a string is not closed", self.text()));
            }
            self.i += 1;
            match c {
                b'"' if self.peek() == b'"' => {
                    self.i += 1;
                    out.push('"');
                }
                b'"' => return Ok(Value::Str(out)),
                b'\'' if self.peek().is_ascii_alphabetic() => {
                    out.push(self.peek().to_ascii_lowercase() as char);
                    self.i += 1;
                }
                c => out.push(c as char),
            }
        }
    }

    fn number(&mut self) -> Eval {
        let start = self.i;
        if self.peek() == b'0' && matches!(self.s.get(self.i + 1), Some(b'x' | b'X')) {
            self.i += 2;
            let from = self.i;
            while self.peek().is_ascii_hexdigit() {
                self.i += 1;
            }
            let digits = std::str::from_utf8(&self.s[from..self.i]).unwrap_or("");
            return u32::from_str_radix(digits, 16)
                .map(|u| i32::try_from(u).map_or_else(|_| Value::float(f64::from(u)), Value::Int))
                .map_err(|_| format!("`{}`: `0x{digits}` is not a number", self.text()));
        }
        while self.peek().is_ascii_digit() {
            self.i += 1;
        }
        let mut float = false;
        if self.peek() == b'.' {
            float = true;
            self.i += 1;
            while self.peek().is_ascii_digit() {
                self.i += 1;
            }
        }
        if matches!(self.peek(), b'e' | b'E')
            && (self.s.get(self.i + 1).is_some_and(u8::is_ascii_digit)
                || (matches!(self.s.get(self.i + 1), Some(b'+' | b'-'))
                    && self.s.get(self.i + 2).is_some_and(u8::is_ascii_digit)))
        {
            float = true;
            self.i += 2;
            while self.peek().is_ascii_digit() {
                self.i += 1;
            }
        }
        let t = std::str::from_utf8(&self.s[start..self.i]).unwrap_or("");
        let x: f64 = t
            .parse()
            .map_err(|_| format!("`{}`: `{t}` is not a number", self.text()))?;
        if !float && x <= f64::from(i32::MAX) {
            return Ok(Value::Int(x as i32));
        }
        Ok(Value::float(x))
    }

    fn identifier(&mut self, evaluate: bool) -> Eval {
        let start = self.i;
        let mut brackets = 0usize;
        while let c @ (b'a'..=b'z' | b'A'..=b'Z' | b'0'..=b'9' | b'_' | b'.' | b'[' | b']') =
            self.peek()
        {
            if c == b'[' {
                brackets += 1;
            } else if c == b']' {
                if brackets == 0 {
                    break;
                }
                brackets -= 1;
            }
            self.i += 1;
        }
        let name = String::from_utf8_lossy(&self.s[start..self.i]).into_owned();
        if self.ws() == b'(' {
            return self.call(&name, evaluate);
        }
        if !evaluate {
            return Ok(Value::Null);
        }
        let scope = self.scope;
        match name.as_str() {
            "true" => return Ok(Value::Bool(true)),
            "false" => return Ok(Value::Bool(false)),
            "null" => return Ok(Value::Null),
            "pi" => return Ok(Value::float(std::f64::consts::PI)),
            "line" => return Ok(Value::Int(scope.line as i32)),
            "iterations" => {
                return scope.iterations.map(|n| Value::Int(n as i32)).ok_or_else(|| {
                    "`iterations` is used outside a `while` loop, where the firmware stops the file"
                        .to_string()
                });
            }
            _ => {}
        }
        if let Some(g) = name.strip_prefix("global.") {
            return match scope.globals.get(g) {
                Some(slot) => slot
                    .value
                    .clone()
                    .map_err(|why| format!("`{name}` is not known: {why}")),
                None => Err(format!(
                    "`{name}` is used before any `global {g} = …` sets it"
                )),
            };
        }
        if let Some(v) = name.strip_prefix("var.") {
            return match scope.locals.iter().rev().find(|l| l.name == v) {
                Some(l) => l
                    .slot
                    .value
                    .clone()
                    .map_err(|why| format!("`{name}` is not known: {why}")),
                None => Err(format!("`{name}` is used before any `var {v} = …` sets it")),
            };
        }
        if let Some(p) = name.strip_prefix("param.") {
            let letter = p.chars().next().filter(|_| p.len() == 1);
            return match letter.and_then(|l| scope.params.get(&l.to_ascii_uppercase())) {
                Some(v) => v.clone(),
                None => Err(format!(
                    "`{name}` is a parameter the macro's caller did not give"
                )),
            };
        }
        Err(format!(
            "`{name}` is the firmware's own state (its object model), whose value the files do not hold"
        ))
    }

    /// A function call, `name(` read.
    fn call(&mut self, name: &str, evaluate: bool) -> Eval {
        self.i += 1;
        if name == "exists" {
            let start = self.i;
            let mut depth = 0usize;
            while self.peek() != 0 && !(self.peek() == b')' && depth == 0) {
                match self.peek() {
                    b'(' | b'[' => depth += 1,
                    b')' | b']' => depth = depth.saturating_sub(1),
                    _ => {}
                }
                self.i += 1;
            }
            if self.peek() != b')' {
                return Err(format!("`{}`: `exists(` is not closed", self.text()));
            }
            let arg = String::from_utf8_lossy(&self.s[start..self.i])
                .trim()
                .to_string();
            self.i += 1;
            if !evaluate {
                return Ok(Value::Null);
            }
            let scope = self.scope;
            let slot = if let Some(g) = arg.strip_prefix("global.") {
                scope.globals.get(g).map(|s| s.certain)
            } else if let Some(v) = arg.strip_prefix("var.") {
                scope
                    .locals
                    .iter()
                    .rev()
                    .find(|l| l.name == v)
                    .map(|l| l.slot.certain)
            } else if let Some(p) = arg.strip_prefix("param.") {
                let l = p.chars().next().map(|c| c.to_ascii_uppercase());
                Some(true).filter(|_| l.is_some_and(|l| scope.params.contains_key(&l)))
            } else {
                return Err(format!(
                    "`exists({arg})` asks about the firmware's own state, which the files do not hold"
                ));
            };
            return match slot {
                Some(true) => Ok(Value::Bool(true)),
                Some(false) => Err(format!(
                    "whether `{arg}` exists is not known: it is set in a block whose condition is not known"
                )),
                None => Ok(Value::Bool(false)),
            };
        }
        let mut args = vec![];
        if self.ws() != b')' {
            loop {
                args.push(self.internal(evaluate, 0)?);
                match self.ws() {
                    b',' => self.i += 1,
                    b')' => break,
                    _ => {
                        return Err(format!(
                            "`{}`: expected `,` or `)` in the arguments of `{name}`",
                            self.text()
                        ));
                    }
                }
            }
        }
        self.i += 1;
        if !evaluate {
            return Ok(Value::Null);
        }
        function(name, &args).map_err(|e| format!("`{}`: {e}", self.text()))
    }
}

/// A Boolean operand, as the firmware's `ConvertToBool` takes it.
fn truth(v: &Value) -> std::result::Result<bool, String> {
    match v {
        Value::Bool(b) => Ok(*b),
        v => Err(format!(
            "a condition or `!`, `&&`, `||` needs a Boolean, not {}",
            v.kind()
        )),
    }
}

/// A binary operator on two evaluated operands.
fn binary(op: u8, invert: bool, a: Value, b: Value) -> std::result::Result<Value, String> {
    use Value::*;
    let numbers = |a: &Value, b: &Value| -> std::result::Result<(f64, f64), String> {
        match (a.number(), b.number()) {
            (Some(x), Some(y)) => Ok((x, y)),
            _ => Err(format!(
                "`{}` takes numbers, not {} and {}",
                op as char,
                a.kind(),
                b.kind()
            )),
        }
    };
    Ok(match op {
        b'+' | b'-' | b'*' => match (&a, &b) {
            (Int(x), Int(y)) => Int(match op {
                b'+' => x.wrapping_add(*y),
                b'-' => x.wrapping_sub(*y),
                _ => x.wrapping_mul(*y),
            }),
            _ => {
                let (x, y) = numbers(&a, &b)?;
                let (x, y) = (x as f32, y as f32);
                Value::float(f64::from(match op {
                    b'+' => x + y,
                    b'-' => x - y,
                    _ => x * y,
                }))
            }
        },
        b'/' => {
            let (x, y) = numbers(&a, &b)?;
            Value::float(f64::from(x as f32 / y as f32))
        }
        b'<' | b'>' => {
            let r = match (&a, &b) {
                (Bool(x), Bool(y)) => {
                    if op == b'>' {
                        *x && !*y
                    } else {
                        !*x && *y
                    }
                }
                _ => {
                    let (x, y) = numbers(&a, &b)?;
                    if op == b'>' { x > y } else { x < y }
                }
            };
            Bool(r != invert)
        }
        b'=' => {
            let r = match (&a, &b) {
                (Null, y) => *y == Null,
                (_, Null) => false,
                (Bool(x), Bool(y)) => x == y,
                (Str(x), Str(y)) => x == y,
                (Int(x), Int(y)) => x == y,
                _ => {
                    let (x, y) = numbers(&a, &b)?;
                    x == y
                }
            };
            Bool(r != invert)
        }
        b'^' => Str(format!("{}{}", show(&a), show(&b))),
        _ => return Err(format!("`{}` is not an operator", op as char)),
    })
}

/// A value as the firmware appends it to a string.
fn show(v: &Value) -> String {
    match v {
        Value::Int(i) => i.to_string(),
        Value::Float(f) => format!("{f}"),
        Value::Bool(b) => b.to_string(),
        Value::Str(s) => s.clone(),
        Value::Array(a) => format!("{{{}}}", a.iter().map(show).collect::<Vec<_>>().join(",")),
        Value::Null => "null".into(),
    }
}

/// The firmware's functions of pure arithmetic; any other is not known
/// here.
fn function(name: &str, args: &[Value]) -> std::result::Result<Value, String> {
    let n = |k: usize| -> std::result::Result<f64, String> {
        args.get(k)
            .and_then(Value::number)
            .ok_or_else(|| format!("`{name}` takes numbers"))
    };
    let want = |count: usize| -> std::result::Result<(), String> {
        if args.len() == count {
            Ok(())
        } else {
            Err(format!("`{name}` takes {count} argument(s)"))
        }
    };
    let f = |x: f64| Ok(Value::float(x));
    match name {
        "abs" => {
            want(1)?;
            match args[0] {
                Value::Int(i) => Ok(Value::Int(i.wrapping_abs())),
                _ => f(n(0)?.abs()),
            }
        }
        "sqrt" | "sin" | "cos" | "tan" | "asin" | "acos" | "atan" | "exp" | "log" | "degrees"
        | "radians" | "floor" | "square" | "isnan" => {
            want(1)?;
            let x = n(0)? as f32;
            match name {
                "sqrt" => f(f64::from(x.sqrt())),
                "sin" => f(f64::from(x.sin())),
                "cos" => f(f64::from(x.cos())),
                "tan" => f(f64::from(x.tan())),
                "asin" => f(f64::from(x.asin())),
                "acos" => f(f64::from(x.acos())),
                "atan" => f(f64::from(x.atan())),
                "exp" => f(f64::from(x.exp())),
                "log" => f(f64::from(x.ln())),
                "degrees" => f(f64::from(x.to_degrees())),
                "radians" => f(f64::from(x.to_radians())),
                "square" => match args[0] {
                    Value::Int(i) => Ok(Value::Int(i.wrapping_mul(i))),
                    _ => f(f64::from(x * x)),
                },
                "floor" => {
                    let v = x.floor();
                    if v.abs() < i32::MAX as f32 {
                        Ok(Value::Int(v as i32))
                    } else {
                        f(f64::from(v))
                    }
                }
                _ => Ok(Value::Bool(x.is_nan())),
            }
        }
        "atan2" => {
            want(2)?;
            f(f64::from((n(0)? as f32).atan2(n(1)? as f32)))
        }
        "min" | "max" => {
            if args.is_empty() {
                return Err(format!("`{name}` takes numbers"));
            }
            let all_int = args.iter().all(|a| matches!(a, Value::Int(_)));
            let mut best = n(0)?;
            for k in 1..args.len() {
                let x = n(k)?;
                if (name == "min" && x < best) || (name == "max" && x > best) {
                    best = x;
                }
            }
            if all_int {
                Ok(Value::Int(best as i32))
            } else {
                f(best)
            }
        }
        "mod" => {
            want(2)?;
            match (&args[0], &args[1]) {
                (Value::Int(a), Value::Int(b)) if *b != 0 => Ok(Value::Int(a.wrapping_rem(*b))),
                _ => f(f64::from((n(0)? as f32) % (n(1)? as f32))),
            }
        }
        other => Err(format!(
            "the function `{other}` is not one pkmcal evaluates (it evaluates arithmetic, trigonometry, min, max, mod and exists)"
        )),
    }
}

/// Evaluate `text` as one expression.
#[doc(hidden)] // public for the integration tests only
pub fn evaluate(text: &str, scope: &Scope<'_>) -> Eval {
    Parser {
        s: text.as_bytes(),
        i: 0,
        depth: 0,
        scope,
    }
    .all()
}

/// A line of a file as the firmware reads it.
#[derive(Debug, Clone)]
struct Line {
    /// Its number in the file (from 1).
    no: usize,
    /// Its indentation.
    indent: usize,
    /// The command text: no line number, checksum, comment or indentation.
    text: String,
    /// A comment at the start of the line (it closes blocks, nothing else).
    comment: bool,
}

/// The lines of a file that the firmware acts on (empty ones and indented
/// comments are not), or a wrong checksum.
fn lines_of(text: &str, file: &Path) -> Result<Vec<Line>> {
    let mut out = vec![];
    for (n, raw) in text.split('\n').enumerate() {
        let raw = if n == 0 {
            raw.trim_start_matches('\u{feff}')
        } else {
            raw
        };
        let b = raw.as_bytes();
        let mut i = 0;
        let mut indent = 0usize;
        let mut sum: u8 = 0;
        let mut number = false;
        // A line number, then white space; or the indentation.
        loop {
            match b.get(i) {
                Some(b'\r') => i += 1,
                Some(c @ (b'N' | b'n')) if !number && indent == 0 => {
                    number = true;
                    sum ^= c;
                    i += 1;
                    while let Some(d) = b.get(i).filter(|d| d.is_ascii_digit()) {
                        sum ^= d;
                        i += 1;
                    }
                }
                Some(c @ b' ') => {
                    sum ^= c;
                    if !number {
                        indent += 1;
                    }
                    i += 1;
                }
                Some(c @ b'\t') => {
                    sum ^= c;
                    if !number {
                        indent = (indent + 4) & !3;
                    }
                    i += 1;
                }
                _ => break,
            }
        }
        let mut command = String::new();
        let (mut quoted, mut braces) = (false, 0usize);
        let mut comment = false;
        let mut checksum: Option<String> = None;
        while let Some(&c) = b.get(i) {
            i += 1;
            if c == b'\r' {
                continue;
            }
            if quoted {
                sum ^= c;
                command.push(c as char);
                if c == b'"' {
                    quoted = false;
                }
                continue;
            }
            match c {
                b'*' if number && braces == 0 => {
                    let digits: String = b[i..]
                        .iter()
                        .take_while(|d| d.is_ascii_digit())
                        .map(|&d| d as char)
                        .collect();
                    checksum = Some(digits);
                    break;
                }
                b';' => {
                    comment = command.is_empty() && indent == 0 && !number;
                    break;
                }
                b'"' => quoted = true,
                b'{' => braces += 1,
                b'}' => braces = braces.saturating_sub(1),
                _ => {}
            }
            sum ^= c;
            command.push(c as char);
        }
        if let Some(digits) = checksum
            && digits.parse::<u32>().ok() != Some(u32::from(sum))
            && (1..=3).contains(&digits.len())
        {
            crate::refuse!(
                file,
                Some((n + 1) as u64),
                "the checksum *{digits} does not match the line (its characters give *{sum}), so RepRapFirmware skips the line; fix the line or remove its line number and checksum"
            );
        }
        let command = command.trim_end().to_string();
        if command.is_empty() && !comment {
            continue;
        }
        out.push(Line {
            no: n + 1,
            indent: if comment { 0 } else { indent },
            text: command,
            comment,
        });
    }
    Ok(out)
}

/// The kinds of block, as the firmware's `BlockType`.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Kind {
    Plain,
    IfTrue,
    IfFalseNoneTrue,
    IfFalseHadTrue,
    /// A loop: the index of its `while` line, its iterations done.
    Loop(usize, u32),
}

#[derive(Debug, Clone)]
struct Block {
    indent: usize,
    kind: Kind,
}

/// A file being run.
struct Frame {
    file: PathBuf,
    lines: Vec<Line>,
    /// The line running.
    pc: usize,
    /// After a macro returns: the next command of the line that called it.
    resume: Option<usize>,
    blocks: Vec<Block>,
    skip_to: Option<usize>,
    locals: Vec<Local>,
    params: HashMap<char, Eval>,
    /// Running `M501`'s file (another `M501` is ignored there).
    in_m501: bool,
    /// The file's end has been met inside a loop (the firmware's virtual
    /// `skip` line is being run).
    at_end: bool,
}

impl Frame {
    fn new(file: PathBuf, lines: Vec<Line>, params: HashMap<char, Eval>, in_m501: bool) -> Self {
        Frame {
            file,
            lines,
            pc: 0,
            resume: None,
            blocks: vec![Block {
                indent: 0,
                kind: Kind::Plain,
            }],
            skip_to: None,
            locals: vec![],
            params,
            in_m501,
            at_end: false,
        }
    }

    fn top(&mut self) -> &mut Block {
        self.blocks.last_mut().expect("the file's own block")
    }

    fn iterations(&self) -> Option<u32> {
        self.blocks.iter().rev().find_map(|b| match b.kind {
            Kind::Loop(_, n) => Some(n),
            _ => None,
        })
    }

    /// Close the innermost block, its variables with it.
    fn end_block(&mut self) {
        if self.blocks.len() > 1 {
            self.blocks.pop();
            let nesting = self.blocks.len() - 1;
            self.locals.retain(|l| l.nesting <= nesting);
        }
    }
}

/// A G or M command of a line, its parameters read as the firmware reads
/// them.
pub struct Command<'a> {
    /// The letter and number (`('M', 665)`).
    pub code: (char, u32),
    /// The file and line.
    pub file: &'a Path,
    pub line: usize,
    /// The command as written.
    pub text: &'a str,
    params: &'a str,
    scope: &'a Scope<'a>,
}

/// Where a parameter's value stops being read: a number (with `SafeStrtod`'s
/// syntax: sign, digits, point, exponent) from `s`, its end; `None` without
/// a digit (or where `s` is not text up to it).
#[doc(hidden)] // public for the integration tests only
pub fn number_at(s: &[u8]) -> Option<(f64, usize)> {
    let text = match std::str::from_utf8(s) {
        Ok(t) => t,
        // The number is ASCII: read up to the first byte that is not text.
        Err(e) => std::str::from_utf8(&s[..e.valid_up_to()]).ok()?,
    };
    crate::gcode::safe_strtod(text)
}

/// The end of the braced expression starting at `s[0] == '{'`.
fn brace_end(s: &[u8]) -> Option<usize> {
    let (mut depth, mut quoted) = (0usize, false);
    for (k, &c) in s.iter().enumerate() {
        match c {
            b'"' => quoted = !quoted,
            b'{' if !quoted => depth += 1,
            b'}' if !quoted => {
                depth -= 1;
                if depth == 0 {
                    return Some(k + 1);
                }
            }
            _ => {}
        }
    }
    None
}

/// Where the firmware's `Seen(letter)` finds a parameter in `params`: just
/// after its first occurrence (either case) outside quotes and braces, an
/// `E` after a digit being an exponent, a letter after `'` another
/// parameter (lower case).
#[doc(hidden)] // public for the integration tests only
pub fn seen(params: &str, letter: char) -> Option<usize> {
    let b = params.as_bytes();
    let (mut quoted, mut escaped, mut braces) = (false, false, 0usize);
    for (k, &c) in b.iter().enumerate() {
        if c == b'"' {
            quoted = !quoted;
            continue;
        }
        if quoted {
            continue;
        }
        if c == b'\'' && !escaped {
            escaped = true;
            continue;
        }
        if braces == 0
            && (c as char).to_ascii_uppercase() == letter
            && !escaped
            && (letter != 'E' || k == 0 || !b[k - 1].is_ascii_digit())
        {
            return Some(k + 1);
        }
        escaped = false;
        if c == b'{' {
            braces += 1;
        } else if c == b'}' && braces > 0 {
            braces -= 1;
        }
    }
    None
}

impl Command<'_> {
    /// An error at this command's line.
    pub fn error(&self, message: impl Into<String>) -> Error {
        Error::at(self.file, Some(self.line as u64), message.into())
    }

    /// Whether the parameter text holds a `(`: the firmware (in its 3D
    /// printer mode) reads the letters inside as parameters, not as a
    /// comment.
    pub fn has_parenthesis(&self) -> bool {
        let b = self.params.as_bytes();
        let (mut quoted, mut braces) = (false, 0usize);
        for &c in b {
            match c {
                b'"' => quoted = !quoted,
                b'{' if !quoted => braces += 1,
                b'}' if !quoted => braces = braces.saturating_sub(1),
                b'(' if !quoted && braces == 0 => return true,
                _ => {}
            }
        }
        false
    }

    /// The values of parameter `letter` as the firmware's `GetFloatArray`
    /// reads them (`L215:215.2:214.9`, an expression `{…}` for any element
    /// but the first, or an array `{a, b, c}` as the whole); `None` when the
    /// command does not have it.
    pub fn floats(&self, letter: char) -> Result<Option<(Vec<f64>, String)>> {
        let Some(at) = seen(self.params, letter) else {
            return Ok(None);
        };
        let b = &self.params.as_bytes()[at..];
        // The parameter as written: up to white space outside braces.
        let word = {
            let mut depth = 0usize;
            let end = b
                .iter()
                .position(|&c| {
                    match c {
                        b'{' => depth += 1,
                        b'}' => depth = depth.saturating_sub(1),
                        _ => {}
                    }
                    depth == 0 && c.is_ascii_whitespace()
                })
                .unwrap_or(b.len());
            short(&self.params[at - 1..at + end], 60)
        };
        let mut out = vec![];
        let mut i = 0;
        loop {
            if b.get(i) == Some(&b'{') {
                let end = brace_end(&b[i..])
                    .ok_or_else(|| self.error(format!("`{word}`: a `{{` is not closed")))?;
                let text = std::str::from_utf8(&b[i..i + end]).unwrap_or("");
                let v = evaluate(text, self.scope).map_err(|why| {
                    self.error(format!(
                        "{why}; write the value of {letter} there as a number"
                    ))
                })?;
                let values: Vec<Value> = match v {
                    Value::Array(a) if out.is_empty() => a,
                    v => vec![v],
                };
                for v in values {
                    match v.number() {
                        Some(x) => out.push(x),
                        None => {
                            return Err(self.error(format!(
                                "`{text}` gives {}, not a number (in `{word}`)",
                                v.kind()
                            )));
                        }
                    }
                }
                i += end;
                if i == end && b.get(i) == Some(&b':') {
                    return Err(self.error(format!(
                        "`{word}`: RepRapFirmware reads an expression in the first place as the whole list and ignores what follows its `:`; write the list as {letter}{{a, b, c}} or give the first value as a number"
                    )));
                }
            } else {
                let Some((x, end)) = number_at(&b[i..]) else {
                    return Err(self.error(format!(
                        "`{word}`: the value of {letter} must be a number{}",
                        if letter == 'L' {
                            " or three separated by ':'"
                        } else {
                            ""
                        }
                    )));
                };
                out.push(x);
                i += end;
                // What follows a number must end it: the firmware reads
                // `R1..0` as 1 and ignores the rest, which is not what was
                // meant.
                if let Some(&c) = b.get(i)
                    && !(c.is_ascii_whitespace() || c == b':' || c.is_ascii_alphabetic())
                {
                    let rest: String = b[i..]
                        .iter()
                        .take_while(|c| !c.is_ascii_whitespace())
                        .map(|&c| c as char)
                        .collect();
                    return Err(self.error(format!(
                        "`{word}`: RepRapFirmware reads {letter} as {x} and ignores `{rest}`; write the number as meant"
                    )));
                }
            }
            if b.get(i) == Some(&b':') {
                i += 1;
            } else {
                break;
            }
        }
        Ok(Some((out, word)))
    }

    /// The string of parameter `letter` (`P"file.g"`, an expression giving a
    /// string, or the text up to the next space).
    fn string(&self, letter: char) -> Result<Option<String>> {
        let Some(at) = seen(self.params, letter) else {
            return Ok(None);
        };
        let rest = self.params[at..].trim_start();
        if rest.starts_with('"') {
            let v = Parser {
                s: rest.as_bytes(),
                i: 0,
                depth: 0,
                scope: self.scope,
            }
            .string()
            .map_err(|why| self.error(why))?;
            return Ok(Some(show(&v)));
        }
        if rest.starts_with('{') {
            let end = brace_end(rest.as_bytes())
                .ok_or_else(|| self.error(format!("`{rest}`: a `{{` is not closed")))?;
            return match evaluate(&rest[..end], self.scope) {
                Ok(Value::Str(s)) => Ok(Some(s)),
                Ok(v) => Err(self.error(format!(
                    "`{}`: the file name is {}, not a string",
                    &rest[..end],
                    v.kind()
                ))),
                Err(why) => Err(self.error(format!(
                    "`{}`: {why}; write the file's name there",
                    &rest[..end]
                ))),
            };
        }
        Ok(Some(
            rest.split_whitespace().next().unwrap_or("").to_string(),
        ))
    }

    /// Every parameter but `skip` as a macro's `param.X` values.
    fn macro_params(&self, skip: char) -> HashMap<char, Eval> {
        let mut out = HashMap::new();
        for c in 'A'..='Z' {
            if c == skip || c == 'G' || c == 'M' {
                continue;
            }
            let Some(at) = seen(self.params, c) else {
                continue;
            };
            let rest = self.params[at..].trim_start();
            let v = if rest.starts_with('"') {
                Parser {
                    s: rest.as_bytes(),
                    i: 0,
                    depth: 0,
                    scope: self.scope,
                }
                .string()
            } else if rest.starts_with('{') {
                match brace_end(rest.as_bytes()) {
                    Some(end) => evaluate(&rest[..end], self.scope),
                    None => Err(format!("`{rest}`: a `{{` is not closed")),
                }
            } else {
                match number_at(rest.as_bytes()) {
                    Some((x, _)) if x.fract() == 0.0 && x.abs() <= f64::from(i32::MAX) => {
                        Ok(Value::Int(x as i32))
                    }
                    Some((x, _)) => Ok(Value::float(x)),
                    None => Err(format!("`{c}{rest}` is not a value pkmcal reads")),
                }
            };
            out.insert(c, v);
        }
        out
    }
}

/// The commands of a line's text: each starts at a `G` or `M` (or `T`)
/// outside quotes and braces and not after `'`; `(letter, number, start,
/// end of code, end)`; a text that does not start with a command is none.
#[doc(hidden)] // public for the integration tests only
pub fn commands_of(text: &str) -> Vec<(char, Option<u32>, usize, usize, usize)> {
    let b = text.as_bytes();
    let mut starts = vec![];
    if let Some(&c) = b.first()
        && matches!(c.to_ascii_uppercase(), b'G' | b'M' | b'T')
    {
        starts.push(0);
    } else {
        return vec![];
    }
    starts.extend(
        crate::gcode::later_command_starts(&b[1..])
            .into_iter()
            .map(|k| k + 1),
    );
    let mut out = vec![];
    for (n, &s) in starts.iter().enumerate() {
        let end = starts.get(n + 1).copied().unwrap_or(b.len());
        let letter = (b[s] as char).to_ascii_uppercase();
        let digits = b[s + 1..end]
            .iter()
            .take_while(|d| d.is_ascii_digit())
            .count();
        let number = std::str::from_utf8(&b[s + 1..s + 1 + digits])
            .ok()
            .and_then(|d| d.parse().ok());
        let mut code_end = s + 1 + digits;
        if number.is_some() && b.get(code_end) == Some(&b'.') {
            code_end += 1;
            if b.get(code_end).is_some_and(u8::is_ascii_digit) {
                code_end += 1;
            }
        }
        out.push((letter, number, s, code_end.min(end), end));
    }
    out
}

/// The meta command a line starts with (2 to 8 lower-case letters ended by
/// a space, a tab, `{`, `"`, `(` or the end), and the rest.
fn meta_of(text: &str) -> Option<(&str, &str)> {
    let n = text.bytes().take_while(u8::is_ascii_lowercase).count();
    if !(2..9).contains(&n) {
        return None;
    }
    let next = text.as_bytes().get(n).copied();
    if !matches!(next, None | Some(b' ' | b'\t' | b'{' | b'"' | b'(')) {
        return None;
    }
    let word = &text[..n];
    matches!(
        word,
        "if" | "elif"
            | "else"
            | "while"
            | "break"
            | "continue"
            | "abort"
            | "var"
            | "global"
            | "set"
            | "echo"
            | "skip"
    )
    .then(|| (word, text[n..].trim()))
}

/// What a run calls back: the commands the caller reads, and the macro
/// files.
pub trait Host {
    /// Whether a G/M code sets what the caller reads (a block with an
    /// unknown condition that holds it is refused).
    fn reads(&self, code: (char, u32)) -> bool;
    /// Act on a command the firmware runs.
    fn command(&mut self, cmd: &Command<'_>) -> Result<()>;
    /// The text and path of the macro `name` (as written after `M98 P`, or
    /// `config-override.g` for `M501`) called from `cmd`.
    fn open(&mut self, name: &str, cmd: &Command<'_>) -> Result<(String, PathBuf)>;
}

/// What a line's commands lead to.
enum Next {
    /// The next line.
    Line,
    /// `M99`: back to the caller.
    Return,
    /// A macro: its path, lines, parameters, whether it runs in `M501`,
    /// and the command of the calling line to go on from.
    Call(PathBuf, Vec<Line>, HashMap<char, Eval>, bool, Option<usize>),
}

/// Run the file `text` (at `file`) as the firmware runs it at start-up,
/// calling `host` back for commands and macros.
pub fn run(text: &str, file: &Path, host: &mut dyn Host) -> Result<()> {
    let mut globals: HashMap<String, Slot> = HashMap::new();
    let mut frames = vec![Frame::new(
        file.to_path_buf(),
        lines_of(text, file)?,
        HashMap::new(),
        false,
    )];
    let (mut lines_run, mut iterations) = (0u64, 0u64);
    loop {
        let open: Vec<PathBuf> = frames.iter().map(|f| f.file.clone()).collect();
        let Some(frame) = frames.last_mut() else {
            break;
        };
        // The end of a file: a loop still open is closed by a virtual
        // `skip` line at indent 0, as the firmware does.
        let line = if frame.pc < frame.lines.len() {
            frame.lines[frame.pc].clone()
        } else if !frame.at_end && frame.iterations().is_some() {
            frame.at_end = true;
            Line {
                no: frame.lines.last().map_or(1, |l| l.no),
                indent: 0,
                text: "skip".into(),
                comment: false,
            }
        } else {
            frames.pop();
            continue;
        };
        let file = frame.file.clone();
        lines_run += 1;
        if lines_run > MAX_LINES_RUN {
            crate::refuse!(
                file,
                Some(line.no as u64),
                "more than {MAX_LINES_RUN} lines are run (loops and macros counted each time); pkmcal stops here"
            );
        }
        let at = |m: String| Error::at(&file, Some(line.no as u64), m);
        let resume = frame.resume.take();
        if resume.is_none() {
            // Blocks skipped, closed and opened, by indentation.
            let mut skipped = Kind::Plain;
            if let Some(s) = frame.skip_to {
                if s < line.indent {
                    frame.pc += 1;
                    continue;
                }
                if s == line.indent {
                    skipped = frame.top().kind;
                    frame.top().kind = Kind::Plain;
                }
                frame.skip_to = None;
            }
            let mut jumped = false;
            while line.indent < frame.top().indent {
                frame.end_block();
                if let Kind::Loop(start, _) = frame.top().kind {
                    frame.pc = start;
                    frame.at_end = false;
                    jumped = true;
                    break;
                }
            }
            if jumped {
                continue;
            }
            if line.indent > frame.top().indent {
                frame.blocks.push(Block {
                    indent: line.indent,
                    kind: Kind::Plain,
                });
            }
            if line.comment {
                frame.pc += 1;
                continue;
            }
            if let Some((word, rest)) = meta_of(&line.text) {
                if meta(
                    frame,
                    &mut globals,
                    &*host,
                    &line,
                    word,
                    rest,
                    skipped,
                    &mut iterations,
                )
                .map_err(at)?
                {
                    return Ok(());
                }
                continue;
            }
        }
        // The line's commands, from the one after a returned macro.
        let commands = commands_of(&line.text);
        let mut next = Next::Line;
        for (k, &(letter, number, start, code_end, end)) in
            commands.iter().enumerate().skip(resume.unwrap_or(0))
        {
            let Some(number) = number else { continue };
            let code = (letter, number);
            let scope = Scope {
                globals: &globals,
                locals: &frame.locals,
                params: &frame.params,
                iterations: frame.iterations(),
                line: line.no,
            };
            let cmd = Command {
                code,
                file: &file,
                line: line.no,
                text: line.text[start..end].trim(),
                params: &line.text[code_end..end],
                scope: &scope,
            };
            let (name, params, m501) = match code {
                ('M', 98) => match cmd.string('P')? {
                    Some(name) => (name, cmd.macro_params('P'), false),
                    None => continue,
                },
                ('M', 501) if !frame.in_m501 => {
                    (super::OVERRIDE_FILE.to_string(), HashMap::new(), true)
                }
                ('M', 99) => {
                    next = Next::Return;
                    break;
                }
                _ => {
                    host.command(&cmd)?;
                    continue;
                }
            };
            let (text, path) = host.open(&name, &cmd)?;
            let same = |a: &Path, b: &Path| {
                a == b || matches!((a.canonicalize(), b.canonicalize()), (Ok(x), Ok(y)) if x == y)
            };
            if let Some(f) = open.iter().find(|f| same(f, &path)) {
                return Err(cmd.error(format!(
                    "`{}` runs {} again, which is already running (the firmware would call it until its stack of {MAX_MACRO_DEPTH} files overflows); remove the call",
                    cmd.text,
                    f.display()
                )));
            }
            if open.len() >= MAX_MACRO_DEPTH {
                return Err(cmd.error(format!(
                    "`{}`: macros call each other more than {MAX_MACRO_DEPTH} files deep, RepRapFirmware's limit; call fewer macros in a chain",
                    cmd.text
                )));
            }
            let lines = lines_of(&text, &path)?;
            let resume = (k + 1 < commands.len()).then_some(k + 1);
            next = Next::Call(path, lines, params, m501 || frame.in_m501, resume);
            break;
        }
        match next {
            Next::Line => frame.pc += 1,
            Next::Return => {
                frames.pop();
            }
            Next::Call(path, lines, params, in_m501, resume) => {
                frame.resume = resume;
                if resume.is_none() {
                    frame.pc += 1;
                }
                frames.push(Frame::new(path, lines, params, in_m501));
            }
        }
    }
    Ok(())
}

/// Run the meta command `word rest` on `line` (`skipped`: the kind of the
/// block whose skipping this line ended); whether it is an `abort`.
#[allow(clippy::too_many_arguments)]
fn meta(
    frame: &mut Frame,
    globals: &mut HashMap<String, Slot>,
    host: &dyn Host,
    line: &Line,
    word: &str,
    rest: &str,
    skipped: Kind,
    iterations: &mut u64,
) -> std::result::Result<bool, String> {
    // A condition's value, or why it is not known.
    let condition = |frame: &Frame, globals: &HashMap<String, Slot>| {
        let scope = Scope {
            globals,
            locals: &frame.locals,
            params: &frame.params,
            iterations: frame.iterations(),
            line: line.no,
        };
        let v = evaluate(rest, &scope)?;
        truth(&v).map_err(|e| format!("`{rest}`: {e}"))
    };
    // An unknown condition: its block is checked and skipped (`Ok`), or
    // refused.
    let unknown = |frame: &mut Frame, globals: &mut HashMap<String, Slot>, why: &str, chain| {
        unknown_block(frame, globals, host, line, word, why, chain).map_err(|e| match e {
            Error::At { message, .. } => message,
            e => e.to_string(),
        })
    };
    match word {
        "if" => match condition(frame, globals) {
            Ok(true) => frame.top().kind = Kind::IfTrue,
            Ok(false) => {
                frame.top().kind = Kind::IfFalseNoneTrue;
                frame.skip_to = Some(frame.top().indent);
            }
            Err(why) => {
                unknown(frame, globals, &why, true)?;
                return Ok(false);
            }
        },
        "elif" => {
            if skipped == Kind::IfFalseNoneTrue {
                match condition(frame, globals) {
                    Ok(true) => frame.top().kind = Kind::IfTrue,
                    Ok(false) => {
                        frame.top().kind = Kind::IfFalseNoneTrue;
                        frame.skip_to = Some(frame.top().indent);
                    }
                    Err(why) => {
                        unknown(frame, globals, &why, true)?;
                        return Ok(false);
                    }
                }
            } else if skipped == Kind::IfFalseHadTrue || frame.top().kind == Kind::IfTrue {
                frame.skip_to = Some(frame.top().indent);
                frame.top().kind = Kind::IfFalseHadTrue;
            } else {
                return Err("`elif` does not follow an `if` block, where RepRapFirmware stops the file; indent the blocks as the firmware reads them".into());
            }
        }
        "else" => {
            if !rest.is_empty() {
                return Err(format!(
                    "`else {rest}`: nothing may follow `else` on its line (RepRapFirmware stops the file here); put the command on the next line, indented"
                ));
            }
            if skipped == Kind::IfFalseNoneTrue {
                frame.top().kind = Kind::Plain;
            } else if skipped == Kind::IfFalseHadTrue || frame.top().kind == Kind::IfTrue {
                frame.skip_to = Some(frame.top().indent);
                frame.top().kind = Kind::Plain;
            } else {
                return Err("`else` does not follow an `if` block, where RepRapFirmware stops the file; indent the blocks as the firmware reads them".into());
            }
        }
        "while" => {
            let pc = frame.pc;
            match frame.top().kind {
                Kind::Loop(start, n) => {
                    *iterations += 1;
                    if *iterations > MAX_ITERATIONS {
                        return Err(format!(
                            "the loops run more than {MAX_ITERATIONS} times in all; pkmcal stops here (does the loop end?)"
                        ));
                    }
                    frame.top().kind = Kind::Loop(start, n + 1);
                }
                _ => frame.top().kind = Kind::Loop(pc, 0),
            }
            match condition(frame, globals) {
                Ok(true) => {}
                Ok(false) => {
                    frame.top().kind = Kind::Plain;
                    frame.skip_to = Some(frame.top().indent);
                }
                Err(why) => {
                    frame.top().kind = Kind::Plain;
                    unknown(frame, globals, &why, false)?;
                    return Ok(false);
                }
            }
        }
        "break" | "continue" => {
            loop {
                if frame.blocks.len() == 1 {
                    return Err(format!(
                        "`{word}` outside a `while` loop, where RepRapFirmware stops the file"
                    ));
                }
                frame.end_block();
                if matches!(frame.top().kind, Kind::Loop(..)) {
                    break;
                }
            }
            if word == "break" {
                frame.top().kind = Kind::Plain;
                frame.skip_to = Some(frame.top().indent);
            } else if let Kind::Loop(start, _) = frame.top().kind {
                frame.pc = start;
                frame.at_end = false;
                return Ok(false);
            }
        }
        "abort" => return Ok(true),
        "var" | "global" => {
            let (name, expr) = assignment(rest)?;
            let exists = if word == "var" {
                frame.locals.iter().any(|l| l.name == name)
            } else {
                globals.get(name).is_some_and(|s| s.certain)
            };
            if exists {
                return Err(format!(
                    "`{word} {name}`: the variable already exists, where RepRapFirmware stops the file; use `set {word}.{name} = …`"
                ));
            }
            let value = {
                let scope = Scope {
                    globals,
                    locals: &frame.locals,
                    params: &frame.params,
                    iterations: frame.iterations(),
                    line: line.no,
                };
                evaluate(expr, &scope)
            };
            let slot = Slot {
                value,
                certain: true,
            };
            if word == "var" {
                let nesting = frame.blocks.len() - 1;
                frame.locals.push(Local {
                    name: name.to_string(),
                    slot,
                    nesting,
                });
            } else {
                globals.insert(name.to_string(), slot);
            }
        }
        "set" => {
            let (target, expr) = assignment(rest)?;
            let value = {
                let scope = Scope {
                    globals,
                    locals: &frame.locals,
                    params: &frame.params,
                    iterations: frame.iterations(),
                    line: line.no,
                };
                evaluate(expr, &scope)
            };
            if let Some(g) = target.strip_prefix("global.") {
                match globals.get_mut(g) {
                    Some(s) => s.value = value,
                    None => {
                        return Err(format!(
                            "`set {target}`: no global `{g}` exists, where RepRapFirmware stops the file; declare it with `global {g} = …` first"
                        ));
                    }
                }
            } else if let Some(v) = target.strip_prefix("var.") {
                match frame.locals.iter_mut().rev().find(|l| l.name == v) {
                    Some(l) => l.slot.value = value,
                    None => {
                        return Err(format!(
                            "`set {target}`: no variable `{v}` exists here, where RepRapFirmware stops the file; declare it with `var {v} = …` first"
                        ));
                    }
                }
            } else {
                return Err(format!(
                    "`set {target}`: `set` takes a `global.` or `var.` variable"
                ));
            }
        }
        _ => {} // echo, skip
    }
    frame.pc += 1;
    Ok(false)
}

/// At most `n` characters of `s`, an ellipsis marking a cut.
fn short(s: &str, n: usize) -> String {
    if s.chars().count() <= n {
        s.to_string()
    } else {
        format!("{}…", s.chars().take(n).collect::<String>())
    }
}

/// `name = expression`.
fn assignment(rest: &str) -> std::result::Result<(&str, &str), String> {
    let Some((name, expr)) = rest.split_once('=') else {
        return Err(format!(
            "`{rest}`: expected `name = value`, where RepRapFirmware stops the file"
        ));
    };
    let name = name.trim();
    let ok = name
        .split('.')
        .all(|p| !p.is_empty() && p.bytes().all(|c| c.is_ascii_alphanumeric() || c == b'_'));
    if !ok {
        return Err(format!(
            "`{name}` is not a variable's name, where RepRapFirmware stops the file"
        ));
    }
    Ok((name, expr.trim()))
}

/// A block whose condition is not known (`line`, a `word` of `if`, `elif`
/// or `while`, and why): refused if any of its lines (with, for an `if`
/// chain, its `elif` and `else` parts) holds what the host reads, a macro,
/// a return or an `abort`; else skipped whole, the variables it sets made
/// unknown (they may or may not be set).
fn unknown_block(
    frame: &mut Frame,
    globals: &mut HashMap<String, Slot>,
    host: &dyn Host,
    line: &Line,
    word: &str,
    why: &str,
    chain: bool,
) -> Result<()> {
    let base = line.indent;
    let mut end = frame.pc + 1;
    loop {
        while end < frame.lines.len() && frame.lines[end].indent > base && !frame.lines[end].comment
        {
            end += 1;
        }
        let next = frame.lines.get(end);
        if chain
            && let Some(l) = next
            && l.indent == base
            && !l.comment
            && matches!(meta_of(&l.text), Some(("elif" | "else", _)))
        {
            end += 1;
            continue;
        }
        break;
    }
    let reason = format!(
        "it is set in the block of `{word}` at line {} of {}, whose condition is not known: {why}",
        line.no,
        frame.file.display()
    );
    for l in &frame.lines[frame.pc + 1..end] {
        let matters = match meta_of(&l.text) {
            Some(("abort" | "break" | "continue", _)) => Some(l.text.clone()),
            Some(("global" | "set", rest)) => {
                if let Ok((name, _)) = assignment(rest) {
                    let g = name.strip_prefix("global.").unwrap_or(name);
                    if !name.starts_with("var.") {
                        let slot = globals.entry(g.to_string()).or_insert(Slot {
                            value: Err(reason.clone()),
                            certain: false,
                        });
                        slot.value = Err(reason.clone());
                    } else if let Some(v) = name.strip_prefix("var.")
                        && let Some(local) = frame.locals.iter_mut().rev().find(|x| x.name == v)
                    {
                        local.slot.value = Err(reason.clone());
                    }
                }
                None
            }
            Some(_) => None,
            None => commands_of(&l.text)
                .iter()
                .find(|&&(letter, number, ..)| {
                    number.is_some_and(|n| {
                        matches!((letter, n), ('M', 98 | 99 | 501)) || host.reads((letter, n))
                    })
                })
                .map(|&(_, _, s, _, e)| l.text[s..e].trim().to_string()),
        };
        if let Some(what) = matters {
            crate::refuse!(
                frame.file,
                Some(line.no as u64),
                "`{word} {}`: {why}; and its block sets what pkmcal reads (`{what}` at line {}), so which value the printer runs cannot be known from the file; write the branch the printer runs without the `{word}`",
                short(line.text[word.len()..].trim(), 60),
                l.no
            );
        }
    }
    frame.top().kind = Kind::Plain;
    frame.pc = end;
    Ok(())
}
