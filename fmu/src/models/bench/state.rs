//! FMU state serialisation: little-endian, versioned, every evolving quantity, no parameters.

use super::mechanics::NZ;
use super::plant::EnergyAccount;
use super::{BenchInputs, BenchPlant, Interlock};
use thiserror::Error;

/// Format tag and version of the serialised state.
const MAGIC: &[u8; 4] = b"KBP1";

/// A serialised state could not be restored.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum StateError {
    /// Fewer bytes than the format needs.
    #[error("state data truncated")]
    Truncated,
    /// Not a plant state of this version.
    #[error("state data has an unknown format tag")]
    BadMagic,
    /// A field holds an impossible value.
    #[error("state data field `{0}` is invalid")]
    Invalid(&'static str),
}

fn take<'a>(input: &mut &'a [u8], n: usize) -> Result<&'a [u8], StateError> {
    if input.len() < n {
        return Err(StateError::Truncated);
    }
    let (head, tail) = input.split_at(n);
    *input = tail;
    Ok(head)
}

fn f64_from(input: &mut &[u8]) -> Result<f64, StateError> {
    let bytes = take(input, 8)?;
    Ok(f64::from_le_bytes(
        bytes.try_into().map_err(|_| StateError::Truncated)?,
    ))
}

fn bool_from(input: &mut &[u8], name: &'static str) -> Result<bool, StateError> {
    match take(input, 1)?[0] {
        0 => Ok(false),
        1 => Ok(true),
        _ => Err(StateError::Invalid(name)),
    }
}

impl BenchPlant {
    /// Appends the state to `out`.
    pub fn encode_state(&self, out: &mut Vec<u8>) {
        let s = &self.state;
        out.extend_from_slice(MAGIC);
        let mut f = |v: f64| out.extend_from_slice(&v.to_le_bytes());
        f(s.time);
        for v in s.z.iter() {
            f(*v);
        }
        for j in 0..2 {
            f(s.direction[j]);
            f(s.saturation[j]);
        }
        for v in s.energy.to_array() {
            f(v);
        }
        f(s.trip.map_or(0.0, |(_, t)| t));
        f(s.inputs.test_command);
        f(s.inputs.load_command);
        out.extend_from_slice(&s.clamp_count.to_le_bytes());
        out.extend_from_slice(&s.trip.map_or(0i32, |(i, _)| i.code()).to_le_bytes());
        for b in [
            s.stuck[0],
            s.stuck[1],
            s.clutch,
            s.last_clamped,
            s.inputs.test_enable,
            s.inputs.load_enable,
            s.inputs.clutch_engage,
            s.inputs.emergency_stop,
        ] {
            out.push(b as u8);
        }
    }

    /// Restores a state written by [`Self::encode_state`], consuming its bytes from `input`.
    /// On error the plant is unchanged.
    pub fn decode_state(&mut self, input: &mut &[u8]) -> Result<(), StateError> {
        let mut cursor = *input;
        if take(&mut cursor, 4)? != MAGIC {
            return Err(StateError::BadMagic);
        }
        let mut s = self.state.clone();
        s.time = f64_from(&mut cursor)?;
        for k in 0..NZ {
            s.z[k] = f64_from(&mut cursor)?;
        }
        for j in 0..2 {
            s.direction[j] = f64_from(&mut cursor)?;
            s.saturation[j] = f64_from(&mut cursor)?;
            if s.direction[j].abs() != 1.0 {
                return Err(StateError::Invalid("direction"));
            }
            if ![-1.0, 0.0, 1.0].contains(&s.saturation[j]) {
                return Err(StateError::Invalid("saturation"));
            }
        }
        let mut energy = [0.0; EnergyAccount::COUNT];
        for v in energy.iter_mut() {
            *v = f64_from(&mut cursor)?;
        }
        s.energy = EnergyAccount::from_array(energy);
        let trip_time = f64_from(&mut cursor)?;
        let mut inputs = BenchInputs {
            test_command: f64_from(&mut cursor)?,
            load_command: f64_from(&mut cursor)?,
            ..BenchInputs::default()
        };
        s.clamp_count = u64::from_le_bytes(
            take(&mut cursor, 8)?
                .try_into()
                .map_err(|_| StateError::Truncated)?,
        );
        let code = i32::from_le_bytes(
            take(&mut cursor, 4)?
                .try_into()
                .map_err(|_| StateError::Truncated)?,
        );
        s.trip = match code {
            0 => None,
            c => Some((
                Interlock::from_code(c).ok_or(StateError::Invalid("trip"))?,
                trip_time,
            )),
        };
        s.stuck[0] = bool_from(&mut cursor, "stuck")?;
        s.stuck[1] = bool_from(&mut cursor, "stuck")?;
        s.clutch = bool_from(&mut cursor, "clutch")?;
        s.last_clamped = bool_from(&mut cursor, "clamped")?;
        inputs.test_enable = bool_from(&mut cursor, "test_enable")?;
        inputs.load_enable = bool_from(&mut cursor, "load_enable")?;
        inputs.clutch_engage = bool_from(&mut cursor, "clutch_engage")?;
        inputs.emergency_stop = bool_from(&mut cursor, "emergency_stop")?;
        s.inputs = inputs;
        if !s.z.iter().all(|v| v.is_finite()) || !s.time.is_finite() {
            return Err(StateError::Invalid("continuous state"));
        }
        self.state = s;
        *input = cursor;
        Ok(())
    }
}
