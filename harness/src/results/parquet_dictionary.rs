//! Dictionary encoding of a Parquet column chunk whose values take few distinct values: a
//! recording's flags, modes, counters, trip codes and held parameters (14 of the SEA
//! scenario's 100 outputs are constant over a run and 5 more take two or three values).
//!
//! Such a chunk is written as Parquet's dictionary page (the distinct values, plain) and one
//! data page of their indexes (`RLE_DICTIONARY`: the RLE / bit-packed hybrid), as the
//! `parquet` crate's and Arrow's writers do by default: a constant column of a full row group
//! takes a few bytes instead of 64 KiB. Every other column stays plain (a double that varies
//! from row to row gains nothing from a dictionary, and the crate's hashing dictionary costs
//! more than the whole plain write). Values are told apart by their bits, so that `-0.0` and
//! `0.0`, and NaNs of different payloads, keep their own entries and read back bit for bit.

/// The most distinct values a dictionary holds here: indexes of at most 4 bits, so that the
/// search for an entry stays a short scan and the indexes take at most half a byte each.
pub(crate) const MAX_ENTRIES: usize = 16;

/// The most 8-value groups in one bit-packed run: its header then takes one byte, as Arrow's
/// and the crate's encoders write them (readers accept longer ones; this stays in the common
/// form).
const MAX_PACKED_GROUPS: usize = 63;

/// A column chunk as a dictionary: its distinct values in the order they first appear, and
/// the data page's bytes (the indexes' bit width, then their RLE / bit-packed hybrid runs).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Dictionary {
    /// The dictionary page: the distinct values' bits, little-endian (plain encoding).
    pub(crate) page: Vec<u8>,
    /// How many distinct values the dictionary page holds.
    pub(crate) entries: u32,
    /// The data page: one byte of bit width, then the indexes' runs.
    pub(crate) indexes: Vec<u8>,
}

/// The distinct values of a column, by their bits.
struct Entries {
    bits: [u64; MAX_ENTRIES],
    len: usize,
}

impl Entries {
    /// The index of `bits`, added if new; `None` once more than [`MAX_ENTRIES`] are needed.
    #[inline]
    fn index_of(&mut self, bits: u64) -> Option<u8> {
        if let Some(i) = self.bits[..self.len].iter().position(|&b| b == bits) {
            return Some(i as u8);
        }
        if self.len == MAX_ENTRIES {
            return None;
        }
        self.bits[self.len] = bits;
        self.len += 1;
        Some((self.len - 1) as u8)
    }
}

/// Bytes of `v` as an unsigned LEB128 varint (a run's header).
fn varint_len(mut v: u64) -> usize {
    let mut n = 1;
    while v >= 0x80 {
        v >>= 7;
        n += 1;
    }
    n
}

fn put_varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

/// `values` as a dictionary, when they take at most [`MAX_ENTRIES`] distinct values and the
/// dictionary and its indexes take at most half the plain page (a second page and a decoding
/// step for the reader are not worth less); `None` otherwise (a column
/// that varies is given up at its 17th distinct value, after a few of them at most).
///
/// The indexes are written as one RLE run per run of equal values when that is smaller than
/// bit-packing them all (a flag that changes a few times per cycle: a few bytes), and
/// bit-packed otherwise (a value that chatters between two or three levels: a bit or two per
/// value).
pub(crate) fn dictionary_of(values: &[f64]) -> Option<Dictionary> {
    if values.is_empty() {
        return None;
    }
    let mut entries = Entries {
        bits: [0; MAX_ENTRIES],
        len: 0,
    };
    // First pass: the entries, and the runs' encoded size (known only once the width is).
    let mut run_headers = 0;
    let mut runs = 0;
    let mut start = 0;
    while start < values.len() {
        let bits = values[start].to_bits();
        entries.index_of(bits)?;
        let len = run_length(&values[start..], bits);
        run_headers += varint_len((len as u64) << 1);
        runs += 1;
        start += len;
    }
    // At least one bit: a single entry's indexes could take none, but not every reader has
    // always read a width of zero.
    let width = (usize::BITS - (entries.len - 1).leading_zeros()).max(1) as usize;
    let rle_size = run_headers + runs * width.div_ceil(8);
    let groups = values.len().div_ceil(8);
    let packed_size = groups * width + groups.div_ceil(MAX_PACKED_GROUPS);
    let size = 1 + rle_size.min(packed_size);
    if entries.len * 8 + size > values.len() * 4 {
        return None;
    }
    let mut indexes = Vec::with_capacity(size);
    indexes.push(width as u8);
    if rle_size <= packed_size {
        write_runs(&mut indexes, values, &mut entries);
    } else {
        write_packed(&mut indexes, values, &mut entries, width);
    }
    debug_assert_eq!(indexes.len(), size);
    let page = entries.bits[..entries.len]
        .iter()
        .flat_map(|b| b.to_le_bytes())
        .collect();
    Some(Dictionary {
        page,
        entries: entries.len as u32,
        indexes,
    })
}

/// How many values at the start of `values` have the bits `bits`: eight at a time while a
/// whole chunk of eight has them (one comparison per value with no branch, which the
/// compiler does in vector registers), then one at a time. A constant column of a full row
/// group is thousands of such values, scanned twice (the size, then the runs).
#[inline]
fn run_length(values: &[f64], bits: u64) -> usize {
    let mut len = 0;
    for chunk in values.chunks_exact(8) {
        if !chunk
            .iter()
            .fold(true, |all, v| all & (v.to_bits() == bits))
        {
            break;
        }
        len += 8;
    }
    len + values[len..]
        .iter()
        .take_while(|v| v.to_bits() == bits)
        .count()
}

/// One RLE run per run of equal values: the run's length, then its index in one byte (the
/// width is at most 4 bits).
fn write_runs(out: &mut Vec<u8>, values: &[f64], entries: &mut Entries) {
    let mut start = 0;
    while start < values.len() {
        let bits = values[start].to_bits();
        let len = run_length(&values[start..], bits);
        put_varint(out, (len as u64) << 1);
        // Every value's entry was found by the first pass.
        out.push(entries.index_of(bits).unwrap_or(0));
        start += len;
    }
}

/// The indexes bit-packed, least significant bits first, in runs of at most
/// [`MAX_PACKED_GROUPS`] groups of 8 (the last group padded with index 0: the page's value
/// count tells the reader where the values end).
fn write_packed(out: &mut Vec<u8>, values: &[f64], entries: &mut Entries, width: usize) {
    for run in values.chunks(MAX_PACKED_GROUPS * 8) {
        let groups = run.len().div_ceil(8);
        put_varint(out, ((groups as u64) << 1) | 1);
        let (mut acc, mut filled) = (0u64, 0usize);
        let mut last = (u64::MAX, 0u8);
        for v in run {
            let bits = v.to_bits();
            if bits != last.0 {
                last = (bits, entries.index_of(bits).unwrap_or(0));
            }
            acc |= u64::from(last.1) << filled;
            filled += width;
            while filled >= 8 {
                out.push(acc as u8);
                acc >>= 8;
                filled -= 8;
            }
        }
        // The padding of the last group: `8 - len % 8` indexes of zero bits.
        let padded_bits = (groups * 8 - run.len()) * width + filled;
        for _ in 0..padded_bits.div_ceil(8) {
            out.push(acc as u8);
            acc >>= 8;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Decodes a data page's indexes (the hybrid's two kinds of runs) and maps them through
    /// the dictionary page: the reader's side, written from the format's description.
    fn decode(d: &Dictionary, count: usize) -> Vec<u64> {
        let dict: Vec<u64> = d
            .page
            .chunks_exact(8)
            .map(|b| u64::from_le_bytes(b.try_into().unwrap()))
            .collect();
        assert_eq!(dict.len(), d.entries as usize);
        let width = d.indexes[0] as usize;
        let mut data = &d.indexes[1..];
        let mut out = Vec::new();
        let varint = |data: &mut &[u8]| {
            let (mut v, mut shift) = (0u64, 0);
            loop {
                let b = data[0];
                *data = &data[1..];
                v |= u64::from(b & 0x7f) << shift;
                shift += 7;
                if b < 0x80 {
                    return v;
                }
            }
        };
        while out.len() < count {
            let header = varint(&mut data);
            if header & 1 == 0 {
                let bytes = width.div_ceil(8);
                let mut index = 0usize;
                for (k, b) in data[..bytes].iter().enumerate() {
                    index |= usize::from(*b) << (8 * k);
                }
                data = &data[bytes..];
                out.extend(std::iter::repeat_n(dict[index], (header >> 1) as usize));
            } else {
                let n = (header >> 1) as usize * 8;
                let bytes = n * width / 8;
                let (mut acc, mut filled, mut used) = (0u64, 0, 0);
                for _ in 0..n {
                    while filled < width {
                        acc |= u64::from(data[used]) << filled;
                        used += 1;
                        filled += 8;
                    }
                    out.push(dict[(acc & ((1 << width) - 1)) as usize]);
                    acc >>= width;
                    filled -= width;
                }
                assert_eq!(used, bytes);
                data = &data[bytes..];
            }
        }
        assert!(data.is_empty(), "{} bytes left", data.len());
        out.truncate(count);
        out
    }

    fn bits(values: &[f64]) -> Vec<u64> {
        values.iter().map(|v| v.to_bits()).collect()
    }

    /// The chunked scan counts what the plain one-by-one scan counts, for runs ending at
    /// every offset around the chunks' boundaries, on bits that differ in one place only
    /// (`-0.0` against `0.0`, two NaN payloads).
    #[test]
    fn run_length_is_the_plain_count() {
        let plain =
            |values: &[f64], bits: u64| values.iter().take_while(|v| v.to_bits() == bits).count();
        let nan2 = f64::from_bits(f64::NAN.to_bits() | 1);
        for (same, other) in [(0.0, -0.0), (f64::NAN, nan2), (1.5, 2.5)] {
            for len in 0..40 {
                for tail in 0..3 {
                    let mut values = vec![same; len];
                    values.extend(std::iter::repeat_n(other, tail));
                    values.extend([same, same]);
                    let bits = f64::to_bits(same);
                    assert_eq!(
                        run_length(&values, bits),
                        plain(&values, bits),
                        "{same} then {other}: {len} + {tail}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_constant_column_is_one_run() {
        let values = vec![2.5; 8192];
        let d = dictionary_of(&values).unwrap();
        assert_eq!(d.entries, 1);
        // The width (1), a 2-byte header (8192 << 1), the index.
        assert_eq!(d.indexes, [1, 0x80, 0x80, 0x01, 0]);
        assert_eq!(decode(&d, values.len()), bits(&values));
    }

    #[test]
    fn few_runs_are_rle_and_chatter_is_bit_packed() {
        // A flag that changes twice: three runs.
        let flag: Vec<f64> = (0..5000).map(|k| f64::from(k > 1000 && k < 3000)).collect();
        let d = dictionary_of(&flag).unwrap();
        assert_eq!(d.entries, 2);
        assert!(d.indexes.len() <= 10, "{:?}", d.indexes);
        assert_eq!(decode(&d, flag.len()), bits(&flag));
        // Three levels changing at every row, a length that is not a multiple of 8 or of a
        // run of 63 groups.
        let chatter: Vec<f64> = (0..8191).map(|k| [-1.5, 0.0, 1.5][k % 3]).collect();
        let d = dictionary_of(&chatter).unwrap();
        assert_eq!((d.entries, d.indexes[0]), (3, 2));
        assert!(d.indexes.len() < 8191 / 4 + 40, "{}", d.indexes.len());
        assert_eq!(decode(&d, chatter.len()), bits(&chatter));
    }

    /// Every width from 1 to 4 bits, both kinds of runs, lengths around a group's and a
    /// packed run's edges.
    #[test]
    fn every_width_and_length_reads_back() {
        for entries in 1..=MAX_ENTRIES {
            for len in [1, 7, 8, 9, 503, 504, 505, 1000] {
                for run in [1, 3, 50] {
                    let values: Vec<f64> = (0..len)
                        .map(|k| ((k / run) % entries) as f64 * 0.25 - 1.0)
                        .collect();
                    match dictionary_of(&values) {
                        Some(d) => assert_eq!(
                            decode(&d, len),
                            bits(&values),
                            "{entries} entries, {len} values, runs of {run}"
                        ),
                        // Given up only where the dictionary would not halve the bytes.
                        None => assert!(len * 4 < entries.min(len) * 8 + 2 + len, "{len}"),
                    }
                }
            }
        }
    }

    /// Values are told apart by their bits: signed zeros and NaN payloads keep their own
    /// entries.
    #[test]
    fn zeros_and_nans_keep_their_bits() {
        let quiet = f64::from_bits(0x7ff8_0000_0000_0001);
        let base = [0.0, -0.0, f64::NAN, quiet, f64::INFINITY];
        let values: Vec<f64> = (0..4000).map(|k| base[(k / 7) % base.len()]).collect();
        let d = dictionary_of(&values).unwrap();
        assert_eq!(d.entries, 5);
        assert_eq!(decode(&d, values.len()), bits(&values));
    }

    /// A column of more than 16 distinct values, or too short to gain, stays plain.
    #[test]
    fn varying_or_tiny_columns_stay_plain() {
        let ramp: Vec<f64> = (0..8192).map(|k| k as f64).collect();
        assert_eq!(dictionary_of(&ramp), None);
        let sixteen_then_more: Vec<f64> = (0..100).map(|k| (k % 17) as f64).collect();
        assert_eq!(dictionary_of(&sixteen_then_more), None);
        assert_eq!(dictionary_of(&[1.0]), None);
        assert_eq!(dictionary_of(&[]), None);
        // 8 + 3 bytes against 16 plain: more than half; against 24, less.
        assert_eq!(dictionary_of(&[1.0; 2]), None);
        assert!(dictionary_of(&[1.0; 3]).is_some());
    }
}
