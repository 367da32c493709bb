//! Acceptance tests of issue 3 for the plant.
