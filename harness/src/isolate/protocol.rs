//! The binary protocol between the master and an FMU host process.
//!
//! Every message is a frame: a little-endian `u32` payload length, then the payload, whose
//! first byte is its kind. The master sends requests ([`REQ_LOAD`], [`REQ_INSTANTIATE`],
//! [`REQ_BATCH`]); the host answers each with exactly one [`FRAME_REPLY`], preceded by any
//! number of [`FRAME_LOG`] frames (the FMU's log messages, sent as the FMU logs them, so that
//! the messages before a crash reach the master).
//!
//! A batch is a sequence of FMI calls (`CALL_*`), each an op byte, a flag byte
//! ([`FLAG_SPECULATIVE`]) and its arguments. The host runs them in order and stops at the first
//! call that returns `fmi2Error`, `fmi2Fatal`, `fmi2Pending` or an invalid status; speculative
//! calls (the reads the master is expected to make after a step) are skipped once an earlier
//! call of the batch returned anything but `fmi2OK` or `fmi2Warning`. The reply carries the
//! number of calls run, then for each its status code (`i32`) and its results.
//!
//! Encodings: integers little-endian, `f64` as its bits, strings and byte strings as a `u32`
//! length then the bytes, arrays as a `u32` count then the elements.

use std::fmt;

/// Request: load the FMU binary (path, preloaded libraries, whether a Python thread state is
/// kept for a binary with an embedded CPython: `u8` 0 or 1).
pub(crate) const REQ_LOAD: u8 = 1;
/// Request: `fmi2Instantiate` (name, GUID, resource URI, visible, loggingOn).
pub(crate) const REQ_INSTANTIATE: u8 = 2;
/// Request: a batch of FMI calls.
pub(crate) const REQ_BATCH: u8 = 3;

/// Frame from the host: the reply to the last request.
pub(crate) const FRAME_REPLY: u8 = b'R';
/// Frame from the host: one log message (status, instance, category, message).
pub(crate) const FRAME_LOG: u8 = b'L';

/// Flag of a call: a read made ahead of the master's request.
pub(crate) const FLAG_SPECULATIVE: u8 = 1;

pub(crate) const CALL_SET_REAL: u8 = 1;
pub(crate) const CALL_SET_INTEGER: u8 = 2;
pub(crate) const CALL_SET_BOOLEAN: u8 = 3;
pub(crate) const CALL_SET_STRING: u8 = 4;
pub(crate) const CALL_GET_REAL: u8 = 5;
pub(crate) const CALL_GET_INTEGER: u8 = 6;
pub(crate) const CALL_GET_BOOLEAN: u8 = 7;
pub(crate) const CALL_GET_STRING: u8 = 8;
pub(crate) const CALL_DO_STEP: u8 = 9;
pub(crate) const CALL_SET_DEBUG_LOGGING: u8 = 10;
pub(crate) const CALL_SETUP_EXPERIMENT: u8 = 11;
pub(crate) const CALL_ENTER_INITIALIZATION: u8 = 12;
pub(crate) const CALL_EXIT_INITIALIZATION: u8 = 13;
pub(crate) const CALL_CANCEL_STEP: u8 = 14;
pub(crate) const CALL_TERMINATE: u8 = 15;
pub(crate) const CALL_RESET: u8 = 16;
pub(crate) const CALL_GET_STATUS: u8 = 17;
pub(crate) const CALL_GET_REAL_STATUS: u8 = 18;
pub(crate) const CALL_GET_INTEGER_STATUS: u8 = 19;
pub(crate) const CALL_GET_BOOLEAN_STATUS: u8 = 20;
pub(crate) const CALL_GET_STRING_STATUS: u8 = 21;
pub(crate) const CALL_GET_OUTPUT_DERIVATIVES: u8 = 22;
pub(crate) const CALL_SET_INPUT_DERIVATIVES: u8 = 23;
pub(crate) const CALL_GET_FMU_STATE: u8 = 24;
pub(crate) const CALL_SET_FMU_STATE: u8 = 25;
pub(crate) const CALL_FREE_FMU_STATE: u8 = 26;
pub(crate) const CALL_SERIALIZE_FMU_STATE: u8 = 27;
pub(crate) const CALL_DESERIALIZE_FMU_STATE: u8 = 28;

/// The largest frame either side accepts (a corrupt length is refused, not allocated).
pub(crate) const MAX_FRAME: usize = 1 << 30;

/// The FMI function a call op stands for.
pub(crate) fn call_name(op: u8) -> &'static str {
    match op {
        CALL_SET_REAL => "fmi2SetReal",
        CALL_SET_INTEGER => "fmi2SetInteger",
        CALL_SET_BOOLEAN => "fmi2SetBoolean",
        CALL_SET_STRING => "fmi2SetString",
        CALL_GET_REAL => "fmi2GetReal",
        CALL_GET_INTEGER => "fmi2GetInteger",
        CALL_GET_BOOLEAN => "fmi2GetBoolean",
        CALL_GET_STRING => "fmi2GetString",
        CALL_DO_STEP => "fmi2DoStep",
        CALL_SET_DEBUG_LOGGING => "fmi2SetDebugLogging",
        CALL_SETUP_EXPERIMENT => "fmi2SetupExperiment",
        CALL_ENTER_INITIALIZATION => "fmi2EnterInitializationMode",
        CALL_EXIT_INITIALIZATION => "fmi2ExitInitializationMode",
        CALL_CANCEL_STEP => "fmi2CancelStep",
        CALL_TERMINATE => "fmi2Terminate",
        CALL_RESET => "fmi2Reset",
        CALL_GET_STATUS => "fmi2GetStatus",
        CALL_GET_REAL_STATUS => "fmi2GetRealStatus",
        CALL_GET_INTEGER_STATUS => "fmi2GetIntegerStatus",
        CALL_GET_BOOLEAN_STATUS => "fmi2GetBooleanStatus",
        CALL_GET_STRING_STATUS => "fmi2GetStringStatus",
        CALL_GET_OUTPUT_DERIVATIVES => "fmi2GetRealOutputDerivatives",
        CALL_SET_INPUT_DERIVATIVES => "fmi2SetRealInputDerivatives",
        CALL_GET_FMU_STATE => "fmi2GetFMUstate",
        CALL_SET_FMU_STATE => "fmi2SetFMUstate",
        CALL_FREE_FMU_STATE => "fmi2FreeFMUstate",
        CALL_SERIALIZE_FMU_STATE => "fmi2SerializeFMUstate",
        CALL_DESERIALIZE_FMU_STATE => "fmi2DeSerializeFMUstate",
        _ => "an unknown call",
    }
}

/// A malformed message.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct ProtocolError(pub(crate) String);

impl fmt::Display for ProtocolError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

/// Appends encoded values to a buffer.
#[derive(Debug, Default)]
pub(crate) struct Enc {
    pub(crate) buf: Vec<u8>,
}

impl Enc {
    /// A buffer with the 4-byte frame header reserved.
    pub(crate) fn frame(kind: u8) -> Enc {
        let mut e = Enc {
            buf: Vec::with_capacity(256),
        };
        e.buf.extend_from_slice(&[0, 0, 0, 0, kind]);
        e
    }
    /// Back to an empty frame of `kind` (keeps the allocation).
    pub(crate) fn reset(&mut self, kind: u8) {
        self.buf.clear();
        self.buf.extend_from_slice(&[0, 0, 0, 0, kind]);
    }
    /// Writes the payload length into the header; the buffer is then a complete frame.
    pub(crate) fn finish(&mut self) -> &[u8] {
        let len = (self.buf.len() - 4) as u32;
        self.buf[..4].copy_from_slice(&len.to_le_bytes());
        &self.buf
    }
    pub(crate) fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }
    pub(crate) fn u32(&mut self, v: u32) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    pub(crate) fn i32(&mut self, v: i32) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    pub(crate) fn u64(&mut self, v: u64) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    pub(crate) fn f64(&mut self, v: f64) {
        self.buf.extend_from_slice(&v.to_bits().to_le_bytes());
    }
    pub(crate) fn bytes(&mut self, v: &[u8]) {
        self.u32(v.len() as u32);
        self.buf.extend_from_slice(v);
    }
    pub(crate) fn str(&mut self, v: &str) {
        self.bytes(v.as_bytes());
    }
    pub(crate) fn u32s(&mut self, v: &[u32]) {
        self.u32(v.len() as u32);
        for &x in v {
            self.u32(x);
        }
    }
    pub(crate) fn i32s(&mut self, v: &[i32]) {
        self.u32(v.len() as u32);
        for &x in v {
            self.i32(x);
        }
    }
    pub(crate) fn f64s(&mut self, v: &[f64]) {
        self.u32(v.len() as u32);
        for &x in v {
            self.f64(x);
        }
    }
}

/// Reads encoded values from a payload.
#[derive(Debug)]
pub(crate) struct Dec<'a> {
    b: &'a [u8],
    pos: usize,
}

impl<'a> Dec<'a> {
    pub(crate) fn new(b: &'a [u8]) -> Dec<'a> {
        Dec { b, pos: 0 }
    }
    fn take(&mut self, n: usize) -> Result<&'a [u8], ProtocolError> {
        if self.b.len() - self.pos < n {
            return Err(ProtocolError(format!(
                "truncated message ({} bytes wanted at offset {} of {})",
                n,
                self.pos,
                self.b.len()
            )));
        }
        let s = &self.b[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }
    pub(crate) fn u8(&mut self) -> Result<u8, ProtocolError> {
        Ok(self.take(1)?[0])
    }
    pub(crate) fn u32(&mut self) -> Result<u32, ProtocolError> {
        Ok(u32::from_le_bytes(
            self.take(4)?.try_into().expect("4 bytes"),
        ))
    }
    pub(crate) fn i32(&mut self) -> Result<i32, ProtocolError> {
        Ok(i32::from_le_bytes(
            self.take(4)?.try_into().expect("4 bytes"),
        ))
    }
    pub(crate) fn u64(&mut self) -> Result<u64, ProtocolError> {
        Ok(u64::from_le_bytes(
            self.take(8)?.try_into().expect("8 bytes"),
        ))
    }
    pub(crate) fn f64(&mut self) -> Result<f64, ProtocolError> {
        Ok(f64::from_bits(self.u64()?))
    }
    /// A count of elements of `size` bytes each, checked against what is left.
    fn count(&mut self, size: usize) -> Result<usize, ProtocolError> {
        let n = self.u32()? as usize;
        if n.saturating_mul(size) > self.b.len() - self.pos {
            return Err(ProtocolError(format!(
                "an array of {n} elements does not fit in the message"
            )));
        }
        Ok(n)
    }
    pub(crate) fn bytes(&mut self) -> Result<&'a [u8], ProtocolError> {
        let n = self.count(1)?;
        self.take(n)
    }
    pub(crate) fn string(&mut self) -> Result<String, ProtocolError> {
        Ok(String::from_utf8_lossy(self.bytes()?).into_owned())
    }
    pub(crate) fn u32s(&mut self) -> Result<Vec<u32>, ProtocolError> {
        let n = self.count(4)?;
        (0..n).map(|_| self.u32()).collect()
    }
    pub(crate) fn i32s(&mut self) -> Result<Vec<i32>, ProtocolError> {
        let n = self.count(4)?;
        (0..n).map(|_| self.i32()).collect()
    }
    /// `n` `f64`s into `out` (which must have `n` elements).
    pub(crate) fn f64s_into(&mut self, out: &mut [f64]) -> Result<(), ProtocolError> {
        let n = self.count(8)?;
        if n != out.len() {
            return Err(ProtocolError(format!(
                "{n} values where {} were asked for",
                out.len()
            )));
        }
        for o in out {
            *o = self.f64()?;
        }
        Ok(())
    }
    /// `n` `i32`s into `out` (which must have `n` elements).
    pub(crate) fn i32s_into(&mut self, out: &mut [i32]) -> Result<(), ProtocolError> {
        let n = self.count(4)?;
        if n != out.len() {
            return Err(ProtocolError(format!(
                "{n} values where {} were asked for",
                out.len()
            )));
        }
        for o in out {
            *o = self.i32()?;
        }
        Ok(())
    }
    pub(crate) fn f64s(&mut self) -> Result<Vec<f64>, ProtocolError> {
        let n = self.count(8)?;
        (0..n).map(|_| self.f64()).collect()
    }
    pub(crate) fn strings(&mut self) -> Result<Vec<String>, ProtocolError> {
        let n = self.count(4)?;
        (0..n).map(|_| self.string()).collect()
    }
    #[cfg(test)]
    pub(crate) fn is_empty(&self) -> bool {
        self.pos == self.b.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_round_trip_and_truncation_is_refused() {
        let mut e = Enc::frame(REQ_BATCH);
        e.u32(7);
        e.f64(-0.0);
        e.f64(f64::NAN);
        e.str("héllo");
        e.u32s(&[1, 2, 3]);
        e.i32s(&[-1]);
        e.f64s(&[1.5, f64::INFINITY]);
        let frame = e.finish().to_vec();
        assert_eq!(
            u32::from_le_bytes(frame[..4].try_into().unwrap()) as usize,
            frame.len() - 4
        );
        let mut d = Dec::new(&frame[4..]);
        assert_eq!(d.u8().unwrap(), REQ_BATCH);
        assert_eq!(d.u32().unwrap(), 7);
        assert_eq!(d.f64().unwrap().to_bits(), (-0.0f64).to_bits());
        assert!(d.f64().unwrap().is_nan());
        assert_eq!(d.string().unwrap(), "héllo");
        assert_eq!(d.u32s().unwrap(), vec![1, 2, 3]);
        assert_eq!(d.i32s().unwrap(), vec![-1]);
        assert_eq!(d.f64s().unwrap(), vec![1.5, f64::INFINITY]);
        assert!(d.is_empty());
        // A count larger than the rest of the message is refused before allocating.
        let mut e = Enc::frame(REQ_BATCH);
        e.u32(u32::MAX);
        let frame = e.finish().to_vec();
        let mut d = Dec::new(&frame[5..]);
        let err = d.f64s().unwrap_err();
        assert!(err.0.contains("does not fit"), "{err}");
        assert!(Dec::new(&[1, 2]).u32().is_err());
    }
}
