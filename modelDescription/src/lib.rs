//! The typed FMI 2.0 model description (`modelDescription.xml`).
//!
//! - [`types`]: one Rust type per schema element, lossless for everything it models.
//! - [`write`](mod@write): [`ModelDescription::to_xml`] writes elements and attributes in schema order,
//!   deterministically (the same value always gives the same bytes).
//! - [`read`]: [`ModelDescription::from_xml`] reads descriptions from any exporter: unknown
//!   attributes and vendor annotations are tolerated, malformed documents are refused with an
//!   error that says where and why.
//! - [`integer_valued`]: Reals that take whole numbers only (a description convention).
//! - [`items`]: the named values of `Integer` types (modes declared as `Integer` for importers
//!   without `Enumeration` support), kept in a vendor annotation.
//! - [`check`]: semantic checks beyond the schema (unique names and value references, a
//!   consistent `ModelStructure`, legal causality/variability/initial combinations).
//! - [`num`](mod@num): numbers in messages, compact and exact (shared by the FMUs and the
//!   harness).

#![warn(missing_docs)]

pub mod check;
pub mod integer_valued;
pub mod items;
pub mod num;
pub mod read;
pub mod types;
pub mod write;

pub use check::{BaseType, Problem};
pub use integer_valued::INTEGER_NOTE;
pub use items::{ITEMS_TOOL, IntegerItems};
pub use read::ParseError;
pub use types::*;
