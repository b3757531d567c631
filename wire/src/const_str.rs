//! Compile-time string building for format strings.
//!
//! `#[derive(IpcMessage)]` and the generic impls (arrays, pointers) build
//! their IPC format strings at compile time from the formats of their parts.
//! Stable Rust cannot size an array from a generic constant, so the buffer
//! has a fixed capacity ([`FORMAT_CAPACITY`]); a format that does not fit is
//! a compile-time error naming the limit.

/// Capacity of a compile-time format buffer, in bytes.
pub const FORMAT_CAPACITY: usize = 1024;

/// A string assembled in a `const` context.
#[derive(Clone, Copy)]
pub struct ConstStr {
    buf: [u8; FORMAT_CAPACITY],
    len: usize,
}

impl ConstStr {
    /// An empty string.
    pub const fn new() -> Self {
        ConstStr {
            buf: [0; FORMAT_CAPACITY],
            len: 0,
        }
    }

    /// Appends `s`.
    ///
    /// # Panics
    /// At compile time, if the result exceeds [`FORMAT_CAPACITY`] bytes.
    pub const fn push_str(mut self, s: &str) -> Self {
        let bytes = s.as_bytes();
        if self.len + bytes.len() > FORMAT_CAPACITY {
            panic!("IPC format string longer than courier_wire::const_str::FORMAT_CAPACITY (1024 bytes): split a struct with many fields into named nested structs (a non-generic struct with fields is referenced by its name); write an enum with many variants as `{{enum : max}}` with `#[ipc(numeric)]`; a generic struct is always written inline, so move its fields into named non-generic structs");
        }
        let mut i = 0;
        while i < bytes.len() {
            self.buf[self.len + i] = bytes[i];
            i += 1;
        }
        self.len += bytes.len();
        self
    }

    /// Appends the decimal form of `n`.
    pub const fn push_usize(self, n: usize) -> Self {
        self.push_u128(n as u128)
    }

    /// Appends the decimal form of `n`.
    pub const fn push_u128(mut self, mut n: u128) -> Self {
        let mut digits = [0u8; 39];
        let mut k = 0;
        loop {
            digits[k] = b'0' + (n % 10) as u8;
            k += 1;
            n /= 10;
            if n == 0 {
                break;
            }
        }
        if self.len + k > FORMAT_CAPACITY {
            panic!("IPC format string longer than courier_wire::const_str::FORMAT_CAPACITY (1024 bytes): split a struct with many fields into named nested structs (a non-generic struct with fields is referenced by its name); write an enum with many variants as `{{enum : max}}` with `#[ipc(numeric)]`; a generic struct is always written inline, so move its fields into named non-generic structs");
        }
        while k > 0 {
            k -= 1;
            self.buf[self.len] = digits[k];
            self.len += 1;
        }
        self
    }

    /// Appends the decimal form of `n` (may be negative).
    pub const fn push_i64(self, n: i64) -> Self {
        self.push_i128(n as i128)
    }

    /// Appends the decimal form of `n` (may be negative).
    pub const fn push_i128(self, n: i128) -> Self {
        if n < 0 {
            self.push_str("-").push_u128(n.unsigned_abs())
        } else {
            self.push_u128(n as u128)
        }
    }

    /// Appends `true` or `false`.
    pub const fn push_bool(self, b: bool) -> Self {
        self.push_str(if b { "true" } else { "false" })
    }

    /// Appends `c` as a Rust character literal (`'a'`).
    pub const fn push_char(self, c: char) -> Self {
        let mut utf8 = [0u8; 4];
        let s: &str = c.encode_utf8(&mut utf8);
        self.push_str("'").push_str(s).push_str("'")
    }

    /// The string built so far.
    pub const fn as_str(&self) -> &str {
        let (head, _) = self.buf.split_at(self.len);
        match core::str::from_utf8(head) {
            Ok(s) => s,
            Err(_) => panic!("ConstStr holds invalid UTF-8"),
        }
    }
}

impl Default for ConstStr {
    fn default() -> Self {
        Self::new()
    }
}

/// Builds the format of a fixed array `[T; n]` from the element's field
/// format: `[elem:n]`, merging nested arrays so that `[[f64; 3]; 2]` gives
/// `[double:2,3]` as the C programmer writes it.
pub const fn array_format(elem: &str, n: usize) -> ConstStr {
    let b = elem.as_bytes();
    // An element that is itself an array `[inner:d1,d2]` merges into `[inner:n,d1,d2]`.
    if !b.is_empty() && b[0] == b'[' && b[b.len() - 1] == b']' {
        // find the top-level ':' (depth 1) that separates the element format from the dims
        let mut depth = 0i32;
        let mut i = 0;
        let mut colon = usize::MAX;
        while i < b.len() {
            match b[i] {
                b'[' | b'{' | b'<' => depth += 1,
                b']' | b'}' | b'>' => depth -= 1,
                b':' if depth == 1 => colon = i,
                _ => {}
            }
            i += 1;
        }
        if colon != usize::MAX {
            let (head, rest) = b.split_at(colon); // head = "[inner", rest = ":d1,d2]"
            let (_, dims) = rest.split_at(1); // "d1,d2]"
            let head = match core::str::from_utf8(head) {
                Ok(s) => s,
                Err(_) => panic!("invalid UTF-8 in format"),
            };
            let dims = match core::str::from_utf8(dims) {
                Ok(s) => s,
                Err(_) => panic!("invalid UTF-8 in format"),
            };
            return ConstStr::new()
                .push_str(head)
                .push_str(":")
                .push_usize(n)
                .push_str(",")
                .push_str(dims);
        }
    }
    ConstStr::new()
        .push_str("[")
        .push_str(elem)
        .push_str(":")
        .push_usize(n)
        .push_str("]")
}

/// The DDS type name of an array of `n` elements of type `elem`, IDL's
/// declarator order: `int32[4]`; an element that is itself an array,
/// `double[3]`, gets the new outer dimension first: `double[2][3]`.
pub const fn array_type_name(elem: &str, n: usize) -> ConstStr {
    let b = elem.as_bytes();
    // where the element's own dimensions start (none: the end): the first
    // `[` outside `<...>`, so that the dimensions of a generic argument
    // (`Stamped<int32[2]>[5]`) stay with it
    let mut at = b.len();
    if !b.is_empty() && b[b.len() - 1] == b']' {
        let mut depth = 0usize;
        let mut i = 0;
        while i < b.len() {
            match b[i] {
                b'<' => depth += 1,
                b'>' => depth = depth.saturating_sub(1),
                b'[' if depth == 0 => {
                    at = i;
                    break;
                }
                _ => {}
            }
            i += 1;
        }
    }
    let (base, dims) = b.split_at(at);
    let (Ok(base), Ok(dims)) = (core::str::from_utf8(base), core::str::from_utf8(dims)) else {
        panic!("invalid UTF-8 in a type name");
    };
    ConstStr::new()
        .push_str(base)
        .push_str("[")
        .push_usize(n)
        .push_str("]")
        .push_str(dims)
}

#[cfg(test)]
mod tests {
    use super::*;

    const A: ConstStr = ConstStr::new()
        .push_str("{int, ")
        .push_usize(42)
        .push_str("}");
    const A_REF: &ConstStr = &A;
    const A_STR: &str = A_REF.as_str();

    #[test]
    fn builds_in_const() {
        assert_eq!(A_STR, "{int, 42}");
        assert_eq!(ConstStr::new().push_i64(-7).as_str(), "-7");
        assert_eq!(ConstStr::new().push_usize(0).as_str(), "0");
    }

    #[test]
    fn array_type_names_put_the_outer_dimension_first() {
        assert_eq!(array_type_name("int32", 4).as_str(), "int32[4]");
        assert_eq!(array_type_name("double[3]", 2).as_str(), "double[2][3]");
        assert_eq!(array_type_name("a::B[1][2]", 7).as_str(), "a::B[7][1][2]");
        assert_eq!(array_type_name("Foo<int32>", 2).as_str(), "Foo<int32>[2]");
        // the dimensions of a generic argument are not the element's
        assert_eq!(
            array_type_name("Stamped<int32[2]>", 5).as_str(),
            "Stamped<int32[2]>[5]"
        );
        assert_eq!(
            array_type_name("Stamped<int32[2]>[5]", 3).as_str(),
            "Stamped<int32[2]>[3][5]"
        );
        assert_eq!(
            array_type_name("a::P<b::Q<double[4]>[2], int32>[7]", 1).as_str(),
            "a::P<b::Q<double[4]>[2], int32>[1][7]"
        );
    }

    #[test]
    fn the_capacity_panic_names_the_ways_out() {
        let r =
            std::panic::catch_unwind(|| ConstStr::new().push_str(&"x".repeat(FORMAT_CAPACITY + 1)));
        let e = r.err().expect("over capacity must panic");
        let msg = e
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| e.downcast_ref::<String>().cloned())
            .unwrap_or_default();
        assert!(msg.contains("named nested structs"), "{msg}");
        assert!(msg.contains("#[ipc(numeric)]"), "{msg}");
        assert!(!msg.contains("give nested structs a format name"), "{msg}");
    }

    #[test]
    fn arrays_merge_dimensions() {
        assert_eq!(array_format("double", 3).as_str(), "[double:3]");
        assert_eq!(array_format("[double:3]", 2).as_str(), "[double:2,3]");
        assert_eq!(array_format("[int:4,5]", 3).as_str(), "[int:3,4,5]");
        // an array of structs that contain arrays is not merged
        assert_eq!(
            array_format("{[int:2], int}", 3).as_str(),
            "[{[int:2], int}:3]"
        );
        assert_eq!(
            array_format("[{int, [int:2]}:3]", 4).as_str(),
            "[{int, [int:2]}:4,3]"
        );
    }
}
