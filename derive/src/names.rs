//! Which strings may name an IPC format: the rule of courier-wire's
//! `format::parse::is_format_name` (a name token that is neither `enum` nor
//! a primitive type name), repeated here because a proc-macro crate cannot
//! depend on the runtime crate. The unit tests below check that the two agree.

/// The primitive type names of IPC format strings (`Primitive::name` in
/// courier-wire): a format of one of these names would be read as the
/// primitive.
pub const PRIMITIVES: &[&str] = &[
    "int", "boolean", "float", "double", "byte", "twobyte", "string", "format", "ubyte", "char",
    "short", "long", "ushort", "uint", "ulong",
];

/// Characters that cannot appear in a format name: IPC's format punctuation
/// (C's lexer ends a name at `{}[]<>,:` and reads `*` and `!` as pointers),
/// and `"`.
const PUNCTUATION: &str = "{}[]<>:,*!\"";

/// Why `name` cannot be an IPC format name, or `None` if it can.
pub fn format_name_problem(name: &str) -> Option<String> {
    let Some(first) = name.chars().next() else {
        return Some("an IPC format name must not be empty".to_string());
    };
    if name
        .chars()
        .any(|c| c.is_whitespace() || PUNCTUATION.contains(c))
    {
        return Some(format!(
            "`{name}` cannot be an IPC format name: a format name must contain no spaces or format punctuation ({{}}[]<>:,*!)"
        ));
    }
    if first.is_ascii_digit() {
        return Some(format!(
            "`{name}` cannot be an IPC format name: it starts with a digit, and IPC reads a token that starts with a digit as a number"
        ));
    }
    if name == "enum" {
        return Some(
            "`enum` cannot be an IPC format name: it is the keyword of `{enum ...}` formats"
                .to_string(),
        );
    }
    if PRIMITIVES.contains(&name) {
        return Some(format!(
            "`{name}` cannot be an IPC format name: it is an IPC primitive type, and IPC would read the name as the primitive"
        ));
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use courier_wire::format::{FormatRegistry, Primitive};

    fn wire_accepts(name: &str) -> bool {
        FormatRegistry::new().define(name, "{int}").is_ok()
    }

    #[test]
    fn primitive_names_match_the_wire_crate() {
        let mut wire: Vec<&str> = Primitive::ALL.iter().map(|p| p.name()).collect();
        let mut here = PRIMITIVES.to_vec();
        wire.sort_unstable();
        here.sort_unstable();
        assert_eq!(here, wire);
    }

    #[test]
    fn agrees_with_the_wire_crate() {
        let names = [
            "Pose", "pose_2", "Größe", "x", "_", "Int", "Double", "integer", "enums", "int",
            "twobyte", "enum", "format", "ulong", "3D", "0", "", "a b", "a,b", "a:b", "a{b", "a<b",
            "a[b", "*a", "!a", "{a",
        ];
        for name in names {
            let derive_ok = format_name_problem(name).is_none();
            // the derive refuses `*`, `!` and `"` anywhere in a name (the
            // wire crate only at its start): stricter, never looser
            let stricter = name.contains(['*', '!', '"']);
            if !stricter {
                assert_eq!(derive_ok, wire_accepts(name), "{name:?}");
            } else {
                assert!(!derive_ok, "{name:?}");
            }
        }
        for p in PRIMITIVES {
            assert!(!wire_accepts(p), "{p}");
        }
    }
}
