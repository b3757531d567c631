//! Compile-fail tests: the derive's error messages (spans and wording).
//! Regenerate the `.stderr` files with `TRYBUILD=overwrite cargo test -p courier-derive --test ui`.

#[test]
fn ui() {
    let t = trybuild::TestCases::new();
    t.compile_fail("tests/ui/*.rs");
}
