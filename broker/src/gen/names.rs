//! Rust names for the input languages' names: `UpperCamelCase` types,
//! `snake_case` fields and modules, keywords escaped.

const KEYWORDS: &[&str] = &[
    "as", "async", "await", "break", "const", "continue", "dyn", "else", "enum", "extern", "false",
    "fn", "for", "if", "impl", "in", "let", "loop", "match", "mod", "move", "mut", "pub", "ref",
    "return", "static", "struct", "trait", "true", "type", "unsafe", "use", "where", "while",
    "abstract", "become", "box", "do", "final", "macro", "override", "priv", "try", "typeof",
    "unsized", "virtual", "yield", "gen",
];

/// Words of a name: split at non-alphanumeric characters and where a
/// lower-case letter or digit is followed by an upper-case one
/// (`envVars` -> `env`, `Vars`; `HTTPServer` -> `HTTP`, `Server`).
pub fn words(s: &str) -> Vec<String> {
    let chars: Vec<char> = s.chars().collect();
    let mut out = Vec::new();
    let mut cur = String::new();
    for (i, &c) in chars.iter().enumerate() {
        if !c.is_ascii_alphanumeric() {
            if !cur.is_empty() {
                out.push(std::mem::take(&mut cur));
            }
            continue;
        }
        if c.is_ascii_uppercase() && !cur.is_empty() {
            let prev = chars[i - 1];
            let next_lower = chars.get(i + 1).is_some_and(|n| n.is_ascii_lowercase());
            if prev.is_ascii_lowercase()
                || prev.is_ascii_digit()
                || (prev.is_ascii_uppercase() && next_lower)
            {
                out.push(std::mem::take(&mut cur));
            }
        }
        cur.push(c);
    }
    if !cur.is_empty() {
        out.push(cur);
    }
    out
}

/// `UpperCamelCase`, as Rust names types: `point-array` -> `PointArray`,
/// `RANGE_SENSOR_DATA_TYPE` -> `RangeSensorDataType`, `T1` -> `T1`.
pub fn type_name(s: &str) -> String {
    let mut out = String::new();
    for w in words(s) {
        let mut cs = w.chars();
        if let Some(first) = cs.next() {
            out.push(first.to_ascii_uppercase());
            let rest: String = cs.collect();
            if w.chars().all(|c| !c.is_ascii_lowercase()) {
                out.push_str(&rest.to_ascii_lowercase());
            } else {
                out.push_str(&rest);
            }
        }
    }
    if out.is_empty() || out.starts_with(|c: char| c.is_ascii_digit()) {
        out.insert(0, 'T');
    }
    escape(out)
}

/// `snake_case`, as Rust names fields and modules: `envVars` -> `env_vars`.
pub fn field_name(s: &str) -> String {
    let mut out = words(s)
        .iter()
        .map(|w| w.to_ascii_lowercase())
        .collect::<Vec<_>>()
        .join("_");
    if out.is_empty() || out.starts_with(|c: char| c.is_ascii_digit()) {
        out.insert_str(0, "f_");
    }
    escape(out)
}

/// A name used as it is (enum variants and constants keep their spelling,
/// which IPC format strings and users' code refer to), made a valid Rust
/// identifier.
pub fn verbatim(s: &str) -> String {
    let mut out: String = s
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if out.is_empty() || out.starts_with(|c: char| c.is_ascii_digit()) {
        out.insert(0, '_');
    }
    escape(out)
}

/// True if `s` is `UpperCamelCase` as rustc's `non_camel_case_types`
/// lint wants it.
pub fn is_camel(s: &str) -> bool {
    let s = s.trim_start_matches("r#");
    s.starts_with(|c: char| c.is_ascii_uppercase()) && !s.contains('_')
}

/// True if clippy's `enum_variant_names` would object: at least three
/// variants starting, or ending, with the same word.
pub fn shared_variant_word(variants: &[&str]) -> bool {
    if variants.len() < 3 {
        return false;
    }
    let ws: Vec<Vec<String>> = variants.iter().map(|v| words(v)).collect();
    let same = |pick: fn(&Vec<String>) -> Option<&String>| {
        let first = pick(&ws[0]);
        first.is_some() && ws.iter().all(|w| w.len() > 1 && pick(w) == first)
    };
    same(|w| w.first()) || same(|w| w.last())
}

/// True if `s` is written all in capitals (clippy's `upper_case_acronyms`).
pub fn is_all_caps(s: &str) -> bool {
    s.chars().filter(char::is_ascii_alphabetic).count() > 1
        && s.chars().all(|c| !c.is_ascii_lowercase())
}

fn escape(s: String) -> String {
    match s.as_str() {
        "self" | "Self" | "super" | "crate" => s + "_",
        k if KEYWORDS.contains(&k) => format!("r#{s}"),
        _ => s,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names() {
        assert_eq!(type_name("point-array"), "PointArray");
        assert_eq!(type_name("RANGE_SENSOR_DATA_TYPE"), "RangeSensorDataType");
        assert_eq!(type_name("T1"), "T1");
        assert_eq!(type_name("AddTwoInts_Request"), "AddTwoIntsRequest");
        assert_eq!(type_name("foo"), "Foo");
        assert_eq!(type_name("2d"), "T2d");
        assert_eq!(type_name("self"), "Self_");
        assert_eq!(field_name("envVars"), "env_vars");
        assert_eq!(field_name("frame_id"), "frame_id");
        assert_eq!(field_name("type"), "r#type");
        assert_eq!(field_name("HTTPServer"), "http_server");
        assert_eq!(verbatim("RED"), "RED");
        assert_eq!(verbatim("match"), "r#match");
        assert!(is_camel("Header") && !is_camel("RED_A") && !is_camel("lower"));
        assert!(is_all_caps("RED") && !is_all_caps("Red") && !is_all_caps("V10"));
    }
}
