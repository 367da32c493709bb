//! The points of a sweep: full grid, Latin hypercube, Sobol, random (all seeded, so the same
//! spec gives the same points on every machine) or the rows of a CSV file.
//!
//! Point `i` of a design is the same whatever runs it: the whole design is computed before
//! any run, in one thread. Random numbers come from SplitMix64 (a fixed, documented generator,
//! not a library's default one whose stream may change between versions); Sobol points from
//! `sobol_burley` (Owen-scrambled, single precision in [0, 1) before scaling to [min, max]).
//! `Integer` variables of the Latin hypercube, Sobol and random designs take the whole value of
//! `[min, max]` split into `max - min + 1` equal bins (`min + floor(u (max - min + 1))`,
//! clamped): each value equally likely, a hypercube's strata whole values when there are as many
//! points as values (rounding the scaled value gave the ends half the weight and made
//! duplicates). A grid's levels of an `Integer` variable take the nearest whole value.

use std::path::Path;

use super::SweepError;
use super::spec::{DesignKind, ParameterType, SOBOL_MAX_POINTS, SpecProblem, SweepSpec};

/// The points of a sweep, one value per parameter each, in spec order.
#[derive(Debug, Clone, PartialEq)]
pub struct Design {
    /// `component.variable` of each parameter.
    pub names: Vec<String>,
    /// The points; point `i` has id `i`.
    pub points: Points,
}

/// Points of `width` values each, stored row-major in one buffer (one allocation for the
/// whole design, not one per point): point `i` is `values[i * width..(i + 1) * width]`.
/// Indexing (`points[i]`, `points[i][d]`) and [`get`](Self::get) give a point as a slice.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Points {
    values: Vec<f64>,
    width: usize,
    len: usize,
}

impl Points {
    /// No points yet, of `width` values each.
    pub fn new(width: usize) -> Points {
        Points {
            values: Vec::new(),
            width,
            len: 0,
        }
    }

    /// `len` points of `width` zeros each.
    fn zeros(width: usize, len: usize) -> Points {
        Points {
            values: vec![0.0; width * len],
            width,
            len,
        }
    }

    /// Appends a point; it must have [`width`](Self::width) values (checked: `false`, and
    /// nothing appended, when it has not).
    #[must_use = "a point of another width is not appended"]
    pub fn push(&mut self, point: &[f64]) -> bool {
        if point.len() != self.width {
            return false;
        }
        self.values.extend_from_slice(point);
        self.len += 1;
        true
    }

    /// The number of points.
    pub fn len(&self) -> usize {
        self.len
    }

    /// No points.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The number of values of each point.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Point `i`, or `None` past the last.
    pub fn get(&self, i: usize) -> Option<&[f64]> {
        (i < self.len).then(|| &self.values[i * self.width..(i + 1) * self.width])
    }

    /// The points in order.
    pub fn iter(&self) -> PointsIter<'_> {
        PointsIter {
            points: self,
            next: 0,
        }
    }

    /// Whether one of the points is `point` (`==` value by value).
    pub fn contains(&self, point: &[f64]) -> bool {
        self.iter().any(|p| p == point)
    }

    /// Every point's values, point after point.
    pub fn as_flat(&self) -> &[f64] {
        &self.values
    }

    /// The points as one vector each.
    pub fn to_rows(&self) -> Vec<Vec<f64>> {
        self.iter().map(<[f64]>::to_vec).collect()
    }
}

impl std::ops::Index<usize> for Points {
    type Output = [f64];

    /// Point `i` (panics past the last, as a slice's index does).
    fn index(&self, i: usize) -> &[f64] {
        assert!(i < self.len, "point {i} of {} points", self.len);
        &self.values[i * self.width..(i + 1) * self.width]
    }
}

impl std::ops::IndexMut<usize> for Points {
    fn index_mut(&mut self, i: usize) -> &mut [f64] {
        assert!(i < self.len, "point {i} of {} points", self.len);
        &mut self.values[i * self.width..(i + 1) * self.width]
    }
}

impl<'a> IntoIterator for &'a Points {
    type Item = &'a [f64];
    type IntoIter = PointsIter<'a>;

    fn into_iter(self) -> PointsIter<'a> {
        self.iter()
    }
}

/// The points of a [`Points`] in order ([`Points::iter`]).
#[derive(Debug, Clone)]
pub struct PointsIter<'a> {
    points: &'a Points,
    next: usize,
}

impl<'a> Iterator for PointsIter<'a> {
    type Item = &'a [f64];

    fn next(&mut self) -> Option<&'a [f64]> {
        let p = self.points.get(self.next)?;
        self.next += 1;
        Some(p)
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        let n = self.points.len - self.next;
        (n, Some(n))
    }
}

impl ExactSizeIterator for PointsIter<'_> {}

/// SplitMix64 (Steele, Lea and Flood 2014): a 64-bit generator whose stream is fixed by its
/// seed.
#[derive(Debug, Clone)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    /// A generator started at `seed`.
    pub fn new(seed: u64) -> SplitMix64 {
        SplitMix64(seed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// A uniform number in [0, 1) with 53 random bits.
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// A uniform integer in [0, n) (n > 0), without modulo bias.
    pub fn below(&mut self, n: u64) -> u64 {
        let zone = u64::MAX - u64::MAX % n;
        loop {
            let x = self.next_u64();
            if x < zone {
                return x % n;
            }
        }
    }
}

fn scale(u: f64, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * u
}

/// The value of a parameter of type `ty` at `u` in [0, 1): [`scale`]d for a Real; for an
/// Integer, the whole value of equal-width bin `floor(u (hi - lo + 1))` (see the module
/// documentation).
fn place(u: f64, lo: f64, hi: f64, ty: ParameterType) -> f64 {
    match ty {
        ParameterType::Real => scale(u, lo, hi),
        ParameterType::Integer => (lo + (u * (hi - lo + 1.0)).floor()).clamp(lo, hi),
    }
}

/// `n` evenly spaced values from `lo` to `hi` (both included; `lo` alone for one level).
pub fn levels(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    if n == 1 {
        return vec![lo];
    }
    (0..n)
        .map(|i| {
            if i == n - 1 {
                hi
            } else {
                lo + (hi - lo) * i as f64 / (n - 1) as f64
            }
        })
        .collect()
}

/// The points of `spec`'s design (after [`Prepared::new`](super::Prepared::new), which sets the
/// parameters' types).
pub fn generate(spec: &SweepSpec) -> Result<Design, SweepError> {
    let dims = spec.parameters.len();
    let bounds: Vec<(f64, f64, ParameterType)> = spec
        .parameters
        .iter()
        .map(|p| (p.min.unwrap_or(0.0), p.max.unwrap_or(0.0), p.ty))
        .collect();
    let mut points: Points = match &spec.design {
        DesignKind::Grid => {
            let axes: Vec<Vec<f64>> = spec
                .parameters
                .iter()
                .map(|p| match (&p.values, p.levels, p.min, p.max) {
                    (Some(v), _, _, _) => v.clone(),
                    (None, Some(n), Some(lo), Some(hi)) => levels(lo, hi, n),
                    _ => Vec::new(),
                })
                .collect();
            let total = axes.iter().try_fold(1usize, |n, a| n.checked_mul(a.len()));
            let n = match total {
                None | Some(0) => {
                    return Err(SweepError::Invalid(vec![spec.problem(
                        0,
                        "empty design: the grid has no points (or more than fit in memory)",
                    )]));
                }
                Some(n) if n > MAX_POINTS => {
                    return Err(SweepError::Invalid(vec![spec.problem(
                        0,
                        format!("the grid has {n} points, more than {MAX_POINTS}"),
                    )]));
                }
                Some(n) => {
                    check_count(spec, n)?;
                    n
                }
            };
            // The full factorial, the first parameter's axis the slowest and the last's the
            // fastest: point i's digits in the mixed radix of the axes' lengths.
            let mut out = Points::zeros(dims, n);
            for i in 0..n {
                let point = &mut out[i];
                let mut rest = i;
                for (d, axis) in axes.iter().enumerate().rev() {
                    point[d] = axis[rest % axis.len()];
                    rest /= axis.len();
                }
            }
            out
        }
        DesignKind::Random { points, seed } => {
            check_count(spec, *points)?;
            let mut rng = SplitMix64::new(*seed);
            let mut out = Points::zeros(dims, *points);
            for i in 0..*points {
                for (v, &(lo, hi, ty)) in out[i].iter_mut().zip(&bounds) {
                    *v = place(rng.next_f64(), lo, hi, ty);
                }
            }
            out
        }
        DesignKind::LatinHypercube { points, seed } => {
            check_count(spec, *points)?;
            let n = *points;
            let mut rng = SplitMix64::new(*seed);
            let mut out = Points::zeros(dims, n);
            for (d, &(lo, hi, ty)) in bounds.iter().enumerate() {
                // A random permutation of the strata (Fisher-Yates), a random place in each.
                let mut strata: Vec<usize> = (0..n).collect();
                for i in (1..n).rev() {
                    let j = rng.below(i as u64 + 1) as usize;
                    strata.swap(i, j);
                }
                for (i, &stratum) in strata.iter().enumerate() {
                    let u = (stratum as f64 + rng.next_f64()) / n as f64;
                    out[i][d] = place(u, lo, hi, ty);
                }
            }
            out
        }
        DesignKind::Sobol { points, seed } => {
            check_count(spec, *points)?;
            if *points > SOBOL_MAX_POINTS {
                return Err(SweepError::Invalid(vec![spec.problem(
                    0,
                    format!("the Sobol design has at most {SOBOL_MAX_POINTS} points, not {points}"),
                )]));
            }
            if dims > sobol_burley::NUM_DIMENSIONS as usize {
                return Err(SweepError::Invalid(vec![spec.problem(
                    0,
                    format!(
                        "the Sobol design has at most {} parameters",
                        sobol_burley::NUM_DIMENSIONS
                    ),
                )]));
            }
            // The spec refuses a seed beyond 32 bits (the scramble's); folding it made seeds
            // 0 and 2^32 + 1 the same design.
            let Ok(seed) = u32::try_from(*seed) else {
                return Err(SweepError::Invalid(vec![spec.problem(
                    0,
                    format!(
                        "the Sobol design's seed is at most {}, not {seed}",
                        u32::MAX
                    ),
                )]));
            };
            let mut out = Points::zeros(dims, *points);
            for i in 0..*points {
                for (d, &(lo, hi, ty)) in bounds.iter().enumerate() {
                    let u = sobol_burley::sample(i as u32, d as u32, seed);
                    out[i][d] = place(f64::from(u), lo, hi, ty);
                }
            }
            out
        }
        DesignKind::Csv(path) => read_csv(spec, path)?,
    };
    // A grid's levels of an Integer variable (a CSV's values are refused unless whole).
    for (d, p) in spec.parameters.iter().enumerate() {
        if p.ty == ParameterType::Integer {
            for i in 0..points.len() {
                points[i][d] = points[i][d].round();
            }
        }
    }
    Ok(Design {
        names: spec.parameters.iter().map(|p| p.name.clone()).collect(),
        points,
    })
}

/// The largest design accepted (ids, journal and table stay manageable).
pub const MAX_POINTS: usize = 10_000_000;

/// The most values of a design, points x parameters: 2^25, 256 MiB of floats. The whole design
/// is made before the first run (and each row keeps its point's values), so [`MAX_POINTS`]
/// alone let 10,000,000 points of 20 parameters take 4.3 GB first. At this bound, 10,000,000
/// points have at most 3 parameters, 1,000,000 points 33. Refused at the spec's `points` line
/// (or a grid's `kind`, a CSV's line of the point beyond it).
pub const MAX_DESIGN_VALUES: usize = 1 << 25;

/// The most points of a design of `parameters` parameters: [`MAX_POINTS`], and
/// [`MAX_DESIGN_VALUES`] values.
pub fn max_points(parameters: usize) -> usize {
    MAX_POINTS.min(MAX_DESIGN_VALUES / parameters.max(1))
}

fn check_count(spec: &SweepSpec, n: usize) -> Result<(), SweepError> {
    let dims = spec.parameters.len();
    if n > max_points(dims) {
        return Err(SweepError::Invalid(vec![spec.problem(
            0,
            format!(
                "{n} points of {dims} parameters, more than {} (at most {MAX_POINTS} points \
                 and {MAX_DESIGN_VALUES} values)",
                max_points(dims)
            ),
        )]));
    }
    Ok(())
}

/// The longest line of a design CSV \[bytes\]: a point's values take a few dozen bytes each, and
/// a longer line (a file without line breaks) is refused at its line instead of being read whole.
pub const MAX_CSV_LINE: usize = 1 << 20;

fn read_csv(spec: &SweepSpec, path: &Path) -> Result<Points, SweepError> {
    let f = std::fs::File::open(path).map_err(|source| SweepError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    read_csv_from(
        spec,
        path,
        std::io::BufReader::new(f),
        max_points(spec.parameters.len()),
    )
}

/// Reads the design CSV `path` from `r` line by line: a header of parameter names, then one
/// point per line. The line of point `max_points + 1` is refused as soon as it is read (with
/// the file and the line), and so is a line longer than [`MAX_CSV_LINE`]: the rest of a huge
/// file is never read. (The whole file was read into memory before its points were counted.)
fn read_csv_from(
    spec: &SweepSpec,
    path: &Path,
    mut r: impl std::io::BufRead,
    max_points: usize,
) -> Result<Points, SweepError> {
    use std::io::{BufRead, Read};
    let problem = |line: usize, message: String| SpecProblem {
        file: path.to_path_buf(),
        line,
        message,
    };
    let mut problems = Vec::new();
    let mut buf = String::new();
    let mut line = 0usize;
    // The next line that is not blank, as (its 1-based number, its text without the line
    // break); None at the end of the file.
    let mut next_line = |buf: &mut String| -> Result<Option<usize>, SweepError> {
        loop {
            buf.clear();
            line += 1;
            let read = (&mut r)
                .take(MAX_CSV_LINE as u64 + 1)
                .read_line(buf)
                .map_err(|source| SweepError::Io {
                    path: path.to_path_buf(),
                    source,
                })?;
            if read == 0 {
                return Ok(None);
            }
            if read > MAX_CSV_LINE && !buf.ends_with('\n') {
                return Err(SweepError::Invalid(vec![problem(
                    line,
                    format!("the line is longer than {MAX_CSV_LINE} bytes"),
                )]));
            }
            let text = buf.trim_end_matches(['\n', '\r']).len();
            buf.truncate(text);
            if !buf.trim().is_empty() {
                return Ok(Some(line));
            }
        }
    };
    if next_line(&mut buf)?.is_none() {
        return Err(SweepError::Invalid(vec![problem(
            0,
            "empty design: the CSV has no header".into(),
        )]));
    }
    let header = std::mem::take(&mut buf);
    // A UTF-8 byte order mark (Excel writes one) is not part of the first column's name.
    let header_text = header.strip_prefix('\u{feff}').unwrap_or(&header);
    let columns: Vec<&str> = header_text.split(',').map(str::trim).collect();
    let mut index = Vec::new();
    for (k, c) in columns.iter().enumerate() {
        match spec.parameters.iter().position(|p| p.name == *c) {
            // A parameter named twice: the point would have a value too many (the sweep
            // failed at its first run, without a line).
            Some(_) if columns[..k].contains(c) => {
                problems.push(problem(1, format!("column '{c}' is given twice")))
            }
            Some(i) => index.push(i),
            None => problems.push(problem(
                1,
                format!("column '{c}' is not a parameter of the spec"),
            )),
        }
    }
    for p in &spec.parameters {
        if !columns.contains(&p.name.as_str()) {
            problems.push(problem(1, format!("no column for parameter '{}'", p.name)));
        }
    }
    if !problems.is_empty() {
        return Err(SweepError::Invalid(problems));
    }
    let mut points = Points::new(columns.len());
    let mut rows = 0usize;
    while let Some(line) = next_line(&mut buf)? {
        rows += 1;
        if rows > max_points {
            problems.push(problem(
                line,
                format!(
                    "more than {max_points} points: the design is refused at this line (at most \
                     {MAX_POINTS} points and {MAX_DESIGN_VALUES} values, points x parameters)"
                ),
            ));
            return Err(SweepError::Invalid(problems));
        }
        let cells: Vec<&str> = buf.split(',').map(str::trim).collect();
        if cells.len() != columns.len() {
            problems.push(problem(
                line,
                format!("{} values for {} columns", cells.len(), columns.len()),
            ));
            continue;
        }
        let mut point = vec![0.0; columns.len()];
        for (k, cell) in cells.iter().enumerate() {
            let par = &spec.parameters[index[k]];
            match cell.parse::<f64>() {
                Ok(v) if v.is_finite() => {
                    if par.min.is_some_and(|lo| v < lo) || par.max.is_some_and(|hi| v > hi) {
                        problems.push(problem(
                            line,
                            format!(
                                "{} = {v} is outside [{}, {}]",
                                par.name,
                                par.min.unwrap_or(f64::NEG_INFINITY),
                                par.max.unwrap_or(f64::INFINITY)
                            ),
                        ));
                    }
                    if par.declared_min.is_some_and(|lo| v < lo)
                        || par.declared_max.is_some_and(|hi| v > hi)
                    {
                        problems.push(problem(
                            line,
                            format!(
                                "{} = {v} is outside the variable's [min, max] = [{}, {}]",
                                par.name,
                                par.declared_min.unwrap_or(f64::NEG_INFINITY),
                                par.declared_max.unwrap_or(f64::INFINITY)
                            ),
                        ));
                    }
                    if par.ty == ParameterType::Integer && v.fract() != 0.0 {
                        problems.push(problem(
                            line,
                            format!("{} is an Integer variable, not {v}", par.name),
                        ));
                    }
                    point[index[k]] = v;
                }
                _ => problems.push(problem(
                    line,
                    format!("'{cell}' for {} is not a finite number", par.name),
                )),
            }
        }
        // `point` has one slot per parameter (made so above).
        let pushed = points.push(&point);
        debug_assert!(pushed, "a CSV point of another width");
    }
    if points.is_empty() && problems.is_empty() {
        problems.push(problem(0, "empty design: the CSV has no points".into()));
    }
    if !problems.is_empty() {
        return Err(SweepError::Invalid(problems));
    }
    Ok(points)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splitmix_matches_the_reference_stream() {
        // The first outputs of SplitMix64 seeded with 1234567 (the reference implementation's
        // test vector).
        let mut r = SplitMix64::new(1234567);
        assert_eq!(r.next_u64(), 6457827717110365317);
        assert_eq!(r.next_u64(), 3203168211198807973);
        assert_eq!(r.next_u64(), 9817491932198370423);
    }

    /// A reader of `head` then `row` repeated `rows` times, counting the bytes it hands out.
    struct Rows {
        data: std::io::Chain<std::io::Cursor<Vec<u8>>, std::io::Take<Repeat>>,
        served: std::rc::Rc<std::cell::Cell<usize>>,
    }

    /// `row` without end.
    struct Repeat(&'static [u8], usize);

    impl std::io::Read for Repeat {
        fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
            for b in buf.iter_mut() {
                *b = self.0[self.1];
                self.1 = (self.1 + 1) % self.0.len();
            }
            Ok(buf.len())
        }
    }

    impl std::io::Read for Rows {
        fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
            let n = self.data.read(buf)?;
            self.served.set(self.served.get() + n);
            Ok(n)
        }
    }

    fn rows(
        head: &str,
        row: &'static str,
        rows: u64,
    ) -> (
        std::io::BufReader<Rows>,
        std::rc::Rc<std::cell::Cell<usize>>,
    ) {
        use std::io::Read;
        let served = std::rc::Rc::new(std::cell::Cell::new(0));
        let data = std::io::Cursor::new(head.as_bytes().to_vec())
            .chain(Repeat(row.as_bytes(), 0).take(rows * row.len() as u64));
        let reader = Rows {
            data,
            served: served.clone(),
        };
        (std::io::BufReader::new(reader), served)
    }

    fn csv_spec() -> SweepSpec {
        let text = "system = \"SEA\"\nfmus = \"/nowhere\"\ncycles = 2\n[design]\nkind = \"csv\"\n\
                    file = \"points.csv\"\n[[parameters]]\nname = \"plant.springStiffness\"\n";
        SweepSpec::parse(text, Path::new("/nowhere/s.toml"), Path::new("/nowhere")).unwrap()
    }

    /// A design CSV is read line by line and refused at the line of its point `max + 1`, naming
    /// the file and that line, without reading the rest: the whole file was read into memory
    /// before its points were counted.
    #[test]
    fn a_csv_design_with_too_many_points_is_refused_at_its_line_before_the_rest_is_read() {
        let spec = csv_spec();
        let path = Path::new("/nowhere/points.csv");
        // Blank lines count as lines, not points.
        let head = "plant.springStiffness\n\n300\n";
        let (r, served) = rows(head, "310\r\n", 1_000_000);
        match read_csv_from(&spec, path, r, 5) {
            Err(SweepError::Invalid(problems)) => {
                assert_eq!(problems.len(), 1, "{problems:?}");
                let e = problems[0].to_string();
                // Header at line 1, a blank line, points 1 to 5 at lines 3 to 7.
                assert_eq!(problems[0].line, 8, "{e}");
                assert!(
                    e.contains("points.csv") && e.contains("more than 5 points"),
                    "{e}"
                );
            }
            other => panic!("{other:?}"),
        }
        // One buffer's worth, not the 5 MB behind it.
        assert!(served.get() <= 64 * 1024, "{} bytes read", served.get());
        // At the bound: every point.
        let (r, _) = rows(head, "310\r\n", 4);
        let points = read_csv_from(&spec, path, r, 5).unwrap();
        assert_eq!(
            points.to_rows(),
            [[300.0], [310.0], [310.0], [310.0], [310.0]]
        );
        // A file without line breaks is refused at its first line too long, not read whole.
        let (r, served) = rows("plant.springStiffness\n", "3", 1 << 30);
        match read_csv_from(&spec, path, r, 5) {
            Err(SweepError::Invalid(problems)) => {
                assert_eq!(problems[0].line, 2, "{problems:?}");
                assert!(problems[0].message.contains("longer than"), "{problems:?}");
            }
            other => panic!("{other:?}"),
        }
        assert!(
            served.get() <= 2 * MAX_CSV_LINE,
            "{} bytes read",
            served.get()
        );
    }

    /// A design CSV naming a parameter twice is refused at line 1 (it passed the check, then
    /// every point had a value too many); a UTF-8 byte order mark before the header is not
    /// part of the first column's name.
    #[test]
    fn a_csv_column_given_twice_is_refused_at_line_one_and_a_bom_is_stripped() {
        let spec = csv_spec();
        let path = Path::new("/nowhere/points.csv");
        let csv = "plant.springStiffness, plant.springStiffness\n300,400\n";
        match read_csv_from(&spec, path, csv.as_bytes(), 5) {
            Err(SweepError::Invalid(problems)) => {
                let e: Vec<String> = problems.iter().map(ToString::to_string).collect();
                assert_eq!(
                    e,
                    ["/nowhere/points.csv, line 1: column 'plant.springStiffness' is given twice"]
                );
            }
            other => panic!("{other:?}"),
        }
        let csv = "\u{feff}plant.springStiffness\r\n300\r\n";
        let points = read_csv_from(&spec, path, csv.as_bytes(), 5).unwrap();
        assert_eq!(points.to_rows(), [[300.0]]);
    }

    /// Integer parameters of the random designs take equal-width bins of `[min, max]`: each
    /// whole value equally likely, and a Latin hypercube of as many points as values takes each
    /// once. Rounding the scaled value gave the ends half the weight and made duplicates.
    #[test]
    fn integer_parameters_take_equal_width_bins() {
        let text = "system = \"SEA\"\nfmus = \"/nowhere\"\ncycles = 2\n[design]\n\
                    kind = \"KIND\"\npoints = N\nseed = SEED\n[[parameters]]\n\
                    name = \"plant.configuration\"\nmin = 0.0\nmax = 2.0\n";
        let design = |kind: &str, n: usize, seed: u64| {
            let text = text
                .replace("KIND", kind)
                .replace("N\n", &format!("{n}\n"))
                .replace("SEED", &seed.to_string());
            let mut spec =
                SweepSpec::parse(&text, Path::new("/nowhere/s.toml"), Path::new("/nowhere"))
                    .unwrap();
            spec.parameters[0].ty = ParameterType::Integer;
            let d = generate(&spec).unwrap();
            d.points.iter().map(|p| p[0]).collect::<Vec<f64>>()
        };
        for kind in ["random", "sobol", "latin-hypercube"] {
            let values = design(kind, 3000, 1);
            for v in [0.0, 1.0, 2.0] {
                let n = values.iter().filter(|&&x| x == v).count();
                assert!((900..=1100).contains(&n), "{kind}: {n} of 3000 are {v}");
            }
        }
        for seed in 0..20 {
            let mut values = design("latin-hypercube", 3, seed);
            values.sort_by(f64::total_cmp);
            assert_eq!(values, [0.0, 1.0, 2.0], "seed {seed}");
        }
    }

    /// A design of more values (points x parameters) than MAX_DESIGN_VALUES is refused, with
    /// the bound: 10,000,000 random points of 20 parameters took 4.3 GB before the first run.
    #[test]
    fn the_design_is_bounded_by_its_values() {
        assert_eq!(max_points(1), MAX_POINTS);
        assert_eq!(max_points(20), MAX_DESIGN_VALUES / 20);
        let spec = csv_spec();
        let (r, _) = rows("plant.springStiffness\n", "310\n", 10);
        let e = read_csv_from(&spec, Path::new("p.csv"), r, 5).unwrap_err();
        assert!(e.to_string().contains("33554432 values"), "{e}");
    }

    /// Every kind of design gives the points it gave when they were stored one vector per
    /// point (their count and bits, in order, hashed and pinned): the tables' parameter
    /// columns and the sweeps' fingerprints are unchanged by the storage. The grid's order is
    /// the first parameter's axis slowest; Integer parameters round (grid) or take bins.
    #[test]
    fn the_designs_points_are_pinned() {
        use sha2::{Digest, Sha256};
        let head = "system = \"SEA\"\nfmus = \"/nowhere\"\ncycles = 2\n";
        let random = "[[parameters]]\nname = \"plant.a\"\nmin = 0.25\nmax = 1.5\n\
                      [[parameters]]\nname = \"plant.b\"\nmin = -3.0\nmax = 9.0\n\
                      [[parameters]]\nname = \"plant.c\"\nmin = 100.0\nmax = 450.0\n";
        let grid = "[[parameters]]\nname = \"plant.a\"\nvalues = [1.0, 2.0, 3.0]\n\
                    [[parameters]]\nname = \"plant.b\"\nmin = 0.0\nmax = 5.0\nlevels = 3\n\
                    [[parameters]]\nname = \"plant.c\"\nmin = 0.0\nmax = 1.0\nlevels = 4\n";
        let digest = |design: &str, parameters: &str| {
            let text = format!("{head}[design]\n{design}\n{parameters}");
            let mut spec =
                SweepSpec::parse(&text, Path::new("/nowhere/s.toml"), Path::new("/nowhere"))
                    .unwrap();
            spec.parameters[1].ty = ParameterType::Integer;
            let d = generate(&spec).unwrap();
            let mut h = Sha256::new();
            h.update((d.points.len() as u64).to_le_bytes());
            for p in d.points.iter() {
                h.update((p.len() as u64).to_le_bytes());
                for v in p.iter() {
                    h.update(v.to_bits().to_le_bytes());
                }
            }
            h.finalize()
                .iter()
                .map(|b| format!("{b:02x}"))
                .collect::<String>()
        };
        let got = [
            digest("kind = \"grid\"", grid),
            digest("kind = \"random\"\npoints = 50\nseed = 7", random),
            digest("kind = \"latin-hypercube\"\npoints = 50\nseed = 7", random),
            digest("kind = \"sobol\"\npoints = 50\nseed = 7", random),
        ];
        assert_eq!(
            got,
            [
                "75dea4587c64cc78b34f720793a24c8c97c67f9a97ca18c0c2c45659838ef283",
                "0bf9f5298e9b3b04bd7ccc9ca9b65067d47c495fc187a97b346bcd6dbf932b66",
                "866f20ee60f7ec6e38cfefa848375a8710438f38a215a4948e243b54a0ad9f5c",
                "e6303740667de8da02307336732aff5e636ea38b99858751375ce3ace24f47c0",
            ]
        );
    }

    /// A point of another width is refused by `push` (nothing appended); indexing, `get`, the
    /// iterator and `contains` see the points row by row.
    #[test]
    fn points_are_rows_of_one_buffer() {
        let mut p = Points::new(2);
        assert!(p.is_empty() && p.get(0).is_none() && p.iter().next().is_none());
        assert!(p.push(&[1.0, 2.0]));
        assert!(!p.push(&[3.0]));
        assert!(!p.push(&[3.0, 4.0, 5.0]));
        assert!(p.push(&[3.0, 4.0]));
        assert_eq!((p.len(), p.width()), (2, 2));
        assert_eq!(p.as_flat(), [1.0, 2.0, 3.0, 4.0]);
        assert_eq!(&p[1], [3.0, 4.0]);
        assert_eq!(p.get(1), Some(&[3.0, 4.0][..]));
        assert_eq!(p.get(2), None);
        assert_eq!(p.iter().len(), 2);
        assert_eq!(p.to_rows(), [[1.0, 2.0], [3.0, 4.0]]);
        assert!(p.contains(&[3.0, 4.0]) && !p.contains(&[2.0, 3.0]));
        p[0][1] = 7.0;
        assert_eq!(p.as_flat(), [1.0, 7.0, 3.0, 4.0]);
        // No values per point: points all the same, the empty slice.
        let mut none = Points::new(0);
        assert!(none.push(&[]) && none.push(&[]));
        assert_eq!(none.iter().collect::<Vec<_>>(), [&[] as &[f64]; 2]);
    }

    #[test]
    fn levels_include_both_ends() {
        assert_eq!(levels(1.0, 3.0, 3), vec![1.0, 2.0, 3.0]);
        assert_eq!(levels(0.1, 0.7, 7)[6], 0.7);
        assert_eq!(levels(5.0, 9.0, 1), vec![5.0]);
    }
}
