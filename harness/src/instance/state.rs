//! Saved FMU states: `fmi2GetFMUstate`, `fmi2SetFMUstate`, `fmi2FreeFMUstate` and their
//! serialization, on an instance in this process or in a host.

use super::*;

/// A saved FMU state (`fmi2FMUstate`), valid for the instance that made it until freed with
/// [`Instance::free_fmu_state`] or the instance is dropped.
#[derive(Debug)]
pub struct FmuState {
    ptr: fmi2FMUstate,
}

impl Instance {
    /// `fmi2GetFMUstate` into `ptr` (NULL: a new state).
    fn get_state_into(&mut self, ptr: &mut fmi2FMUstate) -> Result<Status, FmuError> {
        const NAME: &str = "fmi2GetFMUstate";
        self.alive()?;
        self.has(NAME)?;
        self.promises_state(NAME, false)?;
        let s = dispatch!(self, &NAME,
            l => {
                let f = l.f.get_fmu_state.ok_or(FmuError::Unsupported(NAME))?;
                // SAFETY: valid component; the state is NULL or one made by this instance.
                unsafe { f(l.c, ptr) }
            },
            (r, ctx) => r
                .call(ctx, CALL_GET_FMU_STATE, |e| e.u64(*ptr as usize as u64), false, |d| d.u64())
                .map(|(s, p)| {
                    *ptr = p as usize as fmi2FMUstate;
                    s
                })
        );
        self.check(NAME, s)
    }

    /// `fmi2GetFMUstate`: a new saved state.
    pub fn get_fmu_state(&mut self) -> Result<FmuState, FmuError> {
        let mut ptr: fmi2FMUstate = std::ptr::null_mut();
        self.get_state_into(&mut ptr)?;
        Ok(FmuState { ptr })
    }

    /// `fmi2GetFMUstate` into an existing state (overwrites it).
    pub fn update_fmu_state(&mut self, state: &mut FmuState) -> Result<Status, FmuError> {
        self.get_state_into(&mut state.ptr)
    }

    /// `fmi2SetFMUstate`.
    pub fn set_fmu_state(&mut self, state: &FmuState) -> Result<Status, FmuError> {
        const NAME: &str = "fmi2SetFMUstate";
        self.alive()?;
        self.has(NAME)?;
        self.promises_state(NAME, false)?;
        let s = dispatch!(self, &NAME,
            l => {
                let f = l.f.set_fmu_state.ok_or(FmuError::Unsupported(NAME))?;
                // SAFETY: valid component and a state made by this instance.
                unsafe { f(l.c, state.ptr) }
            },
            (r, ctx) => plain(r, ctx, CALL_SET_FMU_STATE, |e| e.u64(state.ptr as usize as u64))
        );
        self.check(NAME, s)
    }

    /// `fmi2FreeFMUstate`.
    pub fn free_fmu_state(&mut self, state: FmuState) -> Result<Status, FmuError> {
        const NAME: &str = "fmi2FreeFMUstate";
        self.alive()?;
        self.has(NAME)?;
        self.promises_state(NAME, false)?;
        let mut ptr = state.ptr;
        let s = dispatch!(self, &NAME,
            l => {
                let f = l.f.free_fmu_state.ok_or(FmuError::Unsupported(NAME))?;
                // SAFETY: valid component and a state made by this instance.
                unsafe { f(l.c, &mut ptr) }
            },
            (r, ctx) => plain(r, ctx, CALL_FREE_FMU_STATE, |e| e.u64(ptr as usize as u64))
        );
        self.check(NAME, s)
    }

    /// `fmi2SerializedFMUstateSize` + `fmi2SerializeFMUstate`.
    pub fn serialize_fmu_state(&mut self, state: &FmuState) -> Result<Vec<u8>, FmuError> {
        self.alive()?;
        self.has("fmi2SerializedFMUstateSize")?;
        self.has("fmi2SerializeFMUstate")?;
        self.promises_state("fmi2SerializeFMUstate", true)?;
        let (s, buf, name) = dispatch!(self, &"fmi2SerializeFMUstate",
            l => {
                let size_f = l
                    .f
                    .serialized_fmu_state_size
                    .ok_or(FmuError::Unsupported("fmi2SerializedFMUstateSize"))?;
                let ser_f = l
                    .f
                    .serialize_fmu_state
                    .ok_or(FmuError::Unsupported("fmi2SerializeFMUstate"))?;
                let mut size = 0usize;
                // SAFETY: valid component and state.
                let s = unsafe { size_f(l.c, state.ptr, &mut size) };
                if s.0 > 1 {
                    (s, Vec::new(), "fmi2SerializedFMUstateSize")
                } else {
                    let mut buf = vec![0u8; size];
                    // SAFETY: buffer of the announced size.
                    let s = unsafe {
                        ser_f(l.c, state.ptr, buf.as_mut_ptr() as *mut fmi2Byte, size)
                    };
                    (s, buf, "fmi2SerializeFMUstate")
                }
            },
            (r, ctx) => r
                .call(
                    ctx,
                    CALL_SERIALIZE_FMU_STATE,
                    |e| e.u64(state.ptr as usize as u64),
                    false,
                    |d| d.bytes().map(<[u8]>::to_vec),
                )
                .map(|(s, b)| (s, b, "fmi2SerializeFMUstate"))
        );
        self.check(name, s)?;
        Ok(buf)
    }

    /// `fmi2DeSerializeFMUstate`: a new state from bytes made by
    /// [`serialize_fmu_state`](Self::serialize_fmu_state).
    pub fn deserialize_fmu_state(&mut self, bytes: &[u8]) -> Result<FmuState, FmuError> {
        const NAME: &str = "fmi2DeSerializeFMUstate";
        self.alive()?;
        self.has(NAME)?;
        self.promises_state(NAME, true)?;
        let (s, ptr) = dispatch!(self, &NAME,
            l => {
                let f = l.f.deserialize_fmu_state.ok_or(FmuError::Unsupported(NAME))?;
                let mut ptr: fmi2FMUstate = std::ptr::null_mut();
                // SAFETY: buffer of the given length, out pointer NULL (asks for a new state).
                let s = unsafe {
                    f(l.c, bytes.as_ptr() as *const fmi2Byte, bytes.len(), &mut ptr)
                };
                (s, ptr)
            },
            (r, ctx) => r
                .call(ctx, CALL_DESERIALIZE_FMU_STATE, |e| e.bytes(bytes), false, |d| d.u64())
                .map(|(s, p)| (s, p as usize as fmi2FMUstate))
        );
        self.check(NAME, s)?;
        Ok(FmuState { ptr })
    }
}
