//! The importer's logger, called the FMI way: always with the format `"%s"` and the message
//! formatted on our side, with the importer's `componentEnvironment` passed back.

use std::ffi::{CStr, CString};

use super::types::{fmi2CallbackLogger, fmi2ComponentEnvironment, fmi2Status};
use crate::model::LOG_CATEGORIES;

/// Index of a log category in [`LOG_CATEGORIES`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Category {
    /// `logEvents`.
    Events = 0,
    /// `logStatusWarning`.
    Warning = 1,
    /// `logStatusDiscard`.
    Discard = 2,
    /// `logStatusError`.
    Error = 3,
    /// `logStatusFatal`.
    Fatal = 4,
    /// `logCalls`.
    Calls = 5,
}

impl Category {
    fn for_status(status: fmi2Status) -> Category {
        match status {
            fmi2Status::fmi2Warning => Category::Warning,
            fmi2Status::fmi2Discard => Category::Discard,
            fmi2Status::fmi2Error => Category::Error,
            fmi2Status::fmi2Fatal => Category::Fatal,
            _ => Category::Events,
        }
    }
}

/// Where an instance's messages go.
pub struct Logger {
    callback: fmi2CallbackLogger,
    environment: fmi2ComponentEnvironment,
    instance_name: CString,
    debug_logging: bool,
    /// Bit i set: category i of [`LOG_CATEGORIES`] is enabled.
    enabled: u32,
    /// The messages passed on, kept in test builds so unit tests can read what a call logged
    /// (the importer's callback is variadic, which a Rust test cannot define).
    #[cfg(test)]
    pub(crate) captured: std::sync::Mutex<Vec<String>>,
}

// SAFETY: the logger callback and the environment pointer belong to the importer, which by the
// FMI standard may call an instance from any one thread at a time; we only pass them back.
unsafe impl Send for Logger {}

impl Logger {
    /// A logger calling `callback` (may be `None`: then nothing is logged).
    pub fn new(
        callback: fmi2CallbackLogger,
        environment: fmi2ComponentEnvironment,
        instance_name: &CStr,
        debug_logging: bool,
    ) -> Self {
        Self {
            callback,
            environment,
            instance_name: instance_name.to_owned(),
            debug_logging,
            enabled: (1 << LOG_CATEGORIES.len()) - 1,
            #[cfg(test)]
            captured: std::sync::Mutex::default(),
        }
    }

    /// The instance name given to `fmi2Instantiate`.
    pub fn instance_name(&self) -> &CStr {
        &self.instance_name
    }

    /// Applies `fmi2SetDebugLogging`: with no categories, all are switched; otherwise only the
    /// named ones. Unknown names are refused and nothing changes.
    pub fn set_debug_logging(&mut self, on: bool, categories: &[&str]) -> Result<(), String> {
        let mut mask = 0u32;
        for name in categories {
            match LOG_CATEGORIES.iter().position(|(n, _)| n == name) {
                Some(i) => mask |= 1 << i,
                None => {
                    return Err(format!(
                        "unknown log category \"{name}\"; declared categories: {}",
                        LOG_CATEGORIES
                            .iter()
                            .map(|(n, _)| *n)
                            .collect::<Vec<_>>()
                            .join(", ")
                    ));
                }
            }
        }
        if categories.is_empty() {
            mask = (1 << LOG_CATEGORIES.len()) - 1;
        }
        if on {
            self.debug_logging = true;
            self.enabled |= mask;
        } else {
            self.enabled &= !mask;
            if categories.is_empty() {
                self.debug_logging = false;
            }
        }
        Ok(())
    }

    /// Whether a message of `category` would be passed on.
    pub fn enabled(&self, category: Category) -> bool {
        self.callback.is_some() && self.debug_logging && self.enabled & (1 << category as u32) != 0
    }

    /// Logs `message` with `status`. Errors and fatal errors are always passed on (the importer
    /// must learn why a call failed); warnings and discards (a safety trip, the end of a sweep)
    /// unless their category was switched off; other messages only when debug logging is on
    /// and enables their category.
    pub fn log(&self, status: fmi2Status, category: Category, message: &str) {
        let category = if category == Category::Events {
            Category::for_status(status)
        } else {
            category
        };
        let category_on = self.enabled & (1 << category as u32) != 0;
        let pass = match status {
            fmi2Status::fmi2Error | fmi2Status::fmi2Fatal => true,
            fmi2Status::fmi2Warning | fmi2Status::fmi2Discard => category_on,
            _ => self.enabled(category),
        };
        if !pass {
            return;
        }
        #[cfg(test)]
        if let Ok(mut captured) = self.captured.lock() {
            captured.push(message.to_owned());
        }
        let Some(callback) = self.callback else {
            return;
        };
        let text = CString::new(message.replace('\0', "\\0")).unwrap_or_default();
        let cat = CString::new(LOG_CATEGORIES[category as usize].0).unwrap_or_default();
        // SAFETY: the callback comes from the importer's fmi2CallbackFunctions; every pointer
        // passed lives until it returns, and the format "%s" consumes exactly one C string.
        unsafe {
            callback(
                self.environment,
                self.instance_name.as_ptr(),
                status,
                cat.as_ptr(),
                c"%s".as_ptr(),
                text.as_ptr(),
            );
        }
    }
}
