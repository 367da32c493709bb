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
    /// [`Logger::enabled`] of every category at once: `enabled` when there is a callback and
    /// debug logging is on, else 0. Kept by [`Logger::refresh_passing`] whenever a field it
    /// depends on changes, so that the per-call test of the getters, setters and
    /// `fmi2DoStep` (is `logCalls` on?) is one bit test instead of three.
    passing: u32,
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
        let mut logger = Self {
            callback,
            environment,
            instance_name: instance_name.to_owned(),
            debug_logging,
            enabled: (1 << LOG_CATEGORIES.len()) - 1,
            passing: 0,
            #[cfg(test)]
            captured: std::sync::Mutex::default(),
        };
        logger.refresh_passing();
        logger
    }

    /// Recomputes [`Logger::passing`] from the callback, `debug_logging` and `enabled`.
    fn refresh_passing(&mut self) {
        self.passing = if self.callback.is_some() && self.debug_logging {
            self.enabled
        } else {
            0
        };
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
        self.refresh_passing();
        Ok(())
    }

    /// Whether a message of `category` would be passed on: there is a callback, debug logging
    /// is on and the category is enabled (one bit test of the cached mask `passing`).
    #[inline]
    pub fn enabled(&self, category: Category) -> bool {
        self.passing & (1 << category as u32) != 0
    }

    /// [`Logger::enabled`] computed from its definition, for the test of the cached form.
    #[cfg(test)]
    fn enabled_plain(&self, category: Category) -> bool {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fmi2::types::{fmi2ComponentEnvironment, fmi2String};

    /// A callback with the logger's fixed arguments; never called by the test (it only asks
    /// which categories would pass).
    unsafe extern "C" fn silent(
        _: fmi2ComponentEnvironment,
        _: fmi2String,
        _: fmi2Status,
        _: fmi2String,
        _: fmi2String,
    ) {
    }

    const ALL: [Category; 6] = [
        Category::Events,
        Category::Warning,
        Category::Discard,
        Category::Error,
        Category::Fatal,
        Category::Calls,
    ];

    /// The cached [`Logger::enabled`] (one bit test of `passing`) answers what its definition
    /// answers, for every category, with and without a callback, logging on or off from the
    /// start, after every call of a sequence of `fmi2SetDebugLogging`s (all categories, some,
    /// an unknown one, which changes nothing).
    #[test]
    fn the_cached_category_test_is_the_definition() {
        // SAFETY: only the fixed arguments differ from the variadic type, and the test never
        // calls the callback (no message is logged).
        let callback: fmi2CallbackLogger = Some(unsafe {
            std::mem::transmute::<
                unsafe extern "C" fn(
                    fmi2ComponentEnvironment,
                    fmi2String,
                    fmi2Status,
                    fmi2String,
                    fmi2String,
                ),
                unsafe extern "C" fn(
                    fmi2ComponentEnvironment,
                    fmi2String,
                    fmi2Status,
                    fmi2String,
                    fmi2String,
                    ...
                ),
            >(silent)
        });
        let calls: [(bool, &[&str]); 9] = [
            (true, &[]),
            (false, &["logCalls"]),
            (false, &[]),
            (true, &["logCalls", "logStatusWarning"]),
            (true, &["no such category"]),
            (false, &["logStatusWarning"]),
            (true, &["logEvents"]),
            (false, &[]),
            (true, &["logCalls"]),
        ];
        let mut passing = 0;
        for callback in [None, callback] {
            for on in [false, true] {
                let mut logger = Logger::new(callback, std::ptr::null_mut(), c"test", on);
                let check = |logger: &Logger, step: usize| {
                    for c in ALL {
                        assert_eq!(
                            logger.enabled(c),
                            logger.enabled_plain(c),
                            "{c:?} after call {step}, callback {}, on {on}",
                            callback.is_some()
                        );
                    }
                };
                check(&logger, 0);
                for (step, (on, categories)) in calls.iter().enumerate() {
                    let _ = logger.set_debug_logging(*on, categories);
                    check(&logger, step + 1);
                    passing += ALL.iter().filter(|c| logger.enabled(**c)).count();
                }
            }
        }
        // Both answers occur.
        assert!(passing > 10, "{passing}");
    }
}
