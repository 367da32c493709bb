//! The FMU-state calls of a case: get, set, free, serialize and deserialize into the
//! importer's state slots.

use std::ptr::{null, null_mut};
use std::sync::MutexGuard;

use kneebench_fmu::fmi2::instance::reseal_state;
use kneebench_tests::*;

use fmi2Status::{fmi2Error, fmi2OK};

use crate::calls::{Buffer, Damage};
use crate::case::{Blob, Case, Expect, Observation, Slot};
use crate::library::live;
use crate::oracle::{F, Machine, S};

impl<'l> Case<'l> {
    /// The lock, after forgetting a freed address in `slot` that a live state has now (the
    /// allocator gave it to a new state: passing it would name that state).
    pub(crate) fn live_checked(&mut self, slot: usize) -> MutexGuard<'static, Vec<usize>> {
        let live = live();
        if matches!(self.slots[slot], Slot::Dead) && live.contains(&(self.ptrs[slot] as usize)) {
            self.slots[slot] = Slot::Null;
            self.ptrs[slot] = null_mut();
        }
        live
    }

    /// `fmi2GetFMUstate` into `slot`.
    pub(crate) fn get_state(
        &mut self,
        slot: usize,
        null_out: bool,
        before: &Observation,
    ) -> (fmi2StatusCode, Expect) {
        let mut live = self.live_checked(slot);
        let was = self.ptrs[slot];
        let out: *mut fmi2FMUstate = if null_out {
            null_mut()
        } else {
            &mut self.ptrs[slot]
        };
        // SAFETY: see `make`.
        let status = unsafe { (self.lib.raw.get_fmu_state)(self.inst.c, out) };
        let fits = !null_out && matches!(self.slots[slot], Slot::Null | Slot::Live { .. });
        let e = self.state_expect(|| {
            self.expect(F::FmuState, || {
                Expect::Exactly(if fits { fmi2OK } else { fmi2Error })
            })
        });
        if matches!(e, Expect::Exactly(fmi2OK)) && status == fmi2OK {
            if was.is_null() {
                live.push(self.ptrs[slot] as usize);
            } else if self.ptrs[slot] != was {
                drop(live);
                self.fail("fmi2GetFMUstate moved a live state instead of overwriting it".into());
            }
            // The state reads as the instance did (observed before the call).
            self.slots[slot] = Slot::Live {
                model: self.meta.identifier,
                machine: self.m,
                observation: Some(before.clone()),
            };
        } else if self.ptrs[slot] != was {
            drop(live);
            self.fail("a refused fmi2GetFMUstate wrote the state pointer".into());
        }
        (status, e)
    }

    /// `fmi2SetFMUstate` from `slot`.
    pub(crate) fn set_state(&mut self, slot: usize) -> (fmi2StatusCode, Expect) {
        let live = self.live_checked(slot);
        // SAFETY: see `make`.
        let status = unsafe { (self.lib.raw.set_fmu_state)(self.inst.c, self.ptrs[slot]) };
        drop(live);
        let restored = match &self.slots[slot] {
            Slot::Live {
                model,
                machine,
                observation,
            } if *model == self.meta.identifier => Some((*machine, observation.clone())),
            _ => None,
        };
        let e = self.state_expect(|| {
            self.expect(F::FmuState, || {
                Expect::Exactly(if restored.is_some() {
                    fmi2OK
                } else {
                    fmi2Error
                })
            })
        });
        if let (Expect::Exactly(fmi2OK), Some((machine, observation))) = (&e, restored)
            && status == fmi2OK
        {
            self.m = machine;
            if let Some(then) = observation {
                let now = self.observe();
                if now != then {
                    self.fail(format!(
                        "a restored state reads differently from when it was taken: {}",
                        then.difference(&now)
                    ));
                }
            }
        }
        (status, e)
    }

    /// `fmi2FreeFMUstate` of `slot` (through a copy of its pointer when `copy`: the slot then
    /// keeps the dangling pointer).
    pub(crate) fn free_state(
        &mut self,
        slot: usize,
        null_out: bool,
        copy: bool,
    ) -> (fmi2StatusCode, Expect) {
        let mut live = self.live_checked(slot);
        let was = self.ptrs[slot];
        let mut copied = was;
        let out: *mut fmi2FMUstate = if null_out {
            null_mut()
        } else if copy {
            &mut copied
        } else {
            &mut self.ptrs[slot]
        };
        // SAFETY: see `make`.
        let status = unsafe { (self.lib.raw.free_fmu_state)(self.inst.c, out) };
        let want = match self.slots[slot] {
            _ if null_out => fmi2Error,
            Slot::Null | Slot::Live { .. } => fmi2OK,
            Slot::Dead | Slot::Never => fmi2Error,
        };
        let e = self.state_expect(|| self.expect(F::FmuState, || Expect::Exactly(want)));
        if matches!(e, Expect::Exactly(fmi2OK)) && status == fmi2OK && !was.is_null() {
            live.retain(|&p| p != was as usize);
            self.dead.push(was as usize);
            if copy {
                if !copied.is_null() {
                    drop(live);
                    self.fail("fmi2FreeFMUstate did not set the pointer to NULL".into());
                }
                self.slots[slot] = Slot::Dead;
            } else {
                if !self.ptrs[slot].is_null() {
                    drop(live);
                    self.fail("fmi2FreeFMUstate did not set the pointer to NULL".into());
                }
                self.slots[slot] = Slot::Null;
            }
        } else if self.ptrs[slot] != was {
            drop(live);
            self.fail("a refused fmi2FreeFMUstate wrote the state pointer".into());
        }
        (status, e)
    }

    /// `fmi2SerializedFMUstateSize` and `fmi2SerializeFMUstate` of `slot` into `buffer`; the
    /// bytes join the blobs.
    pub(crate) fn serialize(&mut self, slot: usize, buffer: Buffer) -> (fmi2StatusCode, Expect) {
        let lib = self.lib;
        let f = &lib.raw;
        let live = self.live_checked(slot);
        let mut size = 64usize;
        if let Slot::Live { .. } = self.slots[slot]
            && self.meta.states
        {
            // SAFETY: see `make`.
            let s = unsafe { (f.serialized_size)(self.inst.c, self.ptrs[slot], &mut size) };
            assert_eq!(s, fmi2OK, "the size of a live state");
        }
        let length = match buffer {
            Buffer::Exact | Buffer::Null => size,
            Buffer::Larger => size + 17,
            Buffer::Short(k) => usize::from(k) % size.max(1),
        };
        let mut bytes = vec![0u8; length];
        let ptr = if matches!(buffer, Buffer::Null) {
            null_mut()
        } else {
            bytes.as_mut_ptr().cast()
        };
        // SAFETY: see `make`; the buffer holds `length` bytes.
        let status = unsafe { (f.serialize)(self.inst.c, self.ptrs[slot], ptr, length) };
        drop(live);
        let fits = matches!(buffer, Buffer::Exact | Buffer::Larger);
        let e = self.state_expect(|| {
            self.expect(F::FmuState, || match &self.slots[slot] {
                Slot::Live { .. } if fits => Expect::Exactly(fmi2OK),
                _ => Expect::Exactly(fmi2Error),
            })
        });
        if matches!(e, Expect::Exactly(fmi2OK))
            && status == fmi2OK
            && let Slot::Live {
                model,
                machine,
                observation,
            } = &self.slots[slot]
        {
            bytes.truncate(size);
            self.blobs.push(Blob {
                bytes,
                model,
                machine: *machine,
                observation: observation.clone(),
            });
        }
        (status, e)
    }

    /// `fmi2DeSerializeFMUstate` of blob `blob` (modulo their number), damaged, into `slot`.
    pub(crate) fn deserialize(
        &mut self,
        blob: usize,
        damage: &Damage,
        slot: usize,
        null_out: bool,
    ) -> (fmi2StatusCode, Expect) {
        let source = self.blobs[blob % self.blobs.len()].clone();
        let mut bytes = source.bytes.clone();
        let mut machine = source.machine;
        let mut intact = true;
        let mut null_bytes = false;
        // The offset of the state code: magic, version, length, then the GUID and the
        // identifier as length-prefixed strings.
        let code_at = {
            let guid = u32::from_le_bytes(bytes[16..20].try_into().unwrap()) as usize;
            let id_at = 20 + guid;
            let id = u32::from_le_bytes(bytes[id_at..id_at + 4].try_into().unwrap()) as usize;
            id_at + 4 + id
        };
        match damage {
            Damage::None => {}
            Damage::Truncate(k) => {
                bytes.truncate(usize::from(*k) % bytes.len());
                intact = false;
            }
            Damage::Flip(at, x) => {
                let at = usize::from(*at) % bytes.len();
                bytes[at] ^= x;
                intact = false;
            }
            Damage::Append(extra) => {
                bytes.extend_from_slice(extra);
                intact = false;
            }
            Damage::Garbage(g) => {
                bytes = g.clone();
                intact = false;
            }
            Damage::Empty => {
                bytes.clear();
                intact = false;
            }
            Damage::Null => {
                null_bytes = true;
                intact = false;
            }
            Damage::Code(code) => {
                bytes[code_at] = *code;
                reseal_state(&mut bytes);
                match S::from_code(*code) {
                    Some(s) => machine.s = s,
                    None => intact = false,
                }
            }
            Damage::NanTime => {
                // start (8 bytes), has-stop (1), stop (8), then the communication point.
                let at = code_at + 1 + 8 + 1 + 8;
                bytes[at..at + 8].copy_from_slice(&f64::NAN.to_le_bytes());
                reseal_state(&mut bytes);
                intact = false;
            }
        }
        let mut live = self.live_checked(slot);
        let was = self.ptrs[slot];
        let out: *mut fmi2FMUstate = if null_out {
            null_mut()
        } else {
            &mut self.ptrs[slot]
        };
        let (ptr, len): (*const fmi2Byte, usize) = if null_bytes {
            (null(), 16)
        } else {
            (bytes.as_ptr().cast(), bytes.len())
        };
        // SAFETY: see `make`; `ptr` holds `len` bytes or is NULL.
        let status = unsafe { (self.lib.raw.deserialize)(self.inst.c, ptr, len, out) };
        let ok = intact
            && !null_out
            && source.model == self.meta.identifier
            && matches!(self.slots[slot], Slot::Null | Slot::Live { .. });
        let e = self.state_expect(|| {
            self.expect(F::FmuState, || {
                Expect::Exactly(if ok { fmi2OK } else { fmi2Error })
            })
        });
        if matches!(e, Expect::Exactly(fmi2OK)) && status == fmi2OK {
            if was.is_null() {
                live.push(self.ptrs[slot] as usize);
            } else if self.ptrs[slot] != was {
                drop(live);
                self.fail("fmi2DeSerializeFMUstate moved a live state".into());
            }
            let forged = matches!(damage, Damage::Code(_));
            self.slots[slot] = Slot::Live {
                model: source.model,
                machine,
                observation: if forged { None } else { source.observation },
            };
        } else if self.ptrs[slot] != was {
            drop(live);
            self.fail("a refused fmi2DeSerializeFMUstate wrote the state pointer".into());
        }
        (status, e)
    }

    /// `fmi2GetFMUstate` of another instance (`other`, of model `model`, known as `machine`)
    /// into `slot`. That instance provides FMU state in every state.
    pub(crate) fn other_state(
        &mut self,
        other: fmi2Component,
        slot: usize,
        model: &'static str,
        machine: Machine,
    ) -> (fmi2StatusCode, Expect) {
        let mut live = self.live_checked(slot);
        let was = self.ptrs[slot];
        // SAFETY: see `make`.
        let status = unsafe { (self.lib.raw.get_fmu_state)(other, &mut self.ptrs[slot]) };
        let fits = matches!(self.slots[slot], Slot::Null | Slot::Live { .. });
        if fits && status == fmi2OK {
            if was.is_null() {
                live.push(self.ptrs[slot] as usize);
            }
            self.slots[slot] = Slot::Live {
                model,
                machine,
                observation: None,
            };
        }
        drop(live);
        (
            status,
            Expect::Exactly(if fits { fmi2OK } else { fmi2Error }),
        )
    }

    /// A live slot freed through a copy of its pointer; an empty one given a freed address or
    /// one never made.
    pub(crate) fn dangle(&mut self, slot: usize, pick: u8) -> (fmi2StatusCode, Expect) {
        if matches!(self.slots[slot], Slot::Live { .. }) {
            // SAFETY: see `make`.
            return self.free_state(slot, false, true);
        }
        let live = live();
        let freed = (!self.dead.is_empty())
            .then(|| self.dead[usize::from(pick) % self.dead.len()])
            .filter(|p| !live.contains(p));
        match (pick % 3, freed) {
            (0, Some(p)) => {
                self.ptrs[slot] = p as fmi2FMUstate;
                self.slots[slot] = Slot::Dead;
            }
            (1, _) => {
                self.ptrs[slot] = self.never.as_mut_ptr().cast();
                self.slots[slot] = Slot::Never;
            }
            _ => {
                // An address in the first page: no allocation has it.
                self.ptrs[slot] = (0x10 + 8 * usize::from(pick % 16)) as fmi2FMUstate;
                self.slots[slot] = Slot::Never;
            }
        }
        (fmi2OK.into(), Expect::Exactly(fmi2OK))
    }
}
