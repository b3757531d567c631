//! Nothing: the test in `tests/` is the point (a crate whose only
//! dependency on Courier names it `courier2`).
