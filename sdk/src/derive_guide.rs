//! `#[derive(IpcMessage)]`: what it accepts and what it generates.
//!
//! The derive reads a struct or a fieldless enum and emits, at compile
//! time, the CMU IPC format string ([`IpcMessage::FORMAT`](crate::IpcMessage::FORMAT)), IPC
//! marshalling byte-identical to the C library, DDS CDR (XCDR1 and XCDR2),
//! the DDS type name and key. Errors are compile errors pointing at the
//! field or attribute at fault.
//!
//! ```
//! use courier::IpcMessage;
//!
//! #[derive(IpcMessage, Debug, PartialEq)]
//! #[ipc(numeric)]
//! enum Status { Wait, Send, Receive, Listen }
//!
//! #[derive(IpcMessage, Debug, PartialEq)]
//! #[ipc(name = "T1", type_name = "module::T1")]
//! struct T1 { i1: i32, status: Status, matrix: [[f64; 3]; 2], d1: f64 }
//!
//! #[derive(IpcMessage, Debug, PartialEq)]
//! #[ipc(extensibility = "appendable")]
//! struct T2 {
//!     #[ipc(key)]
//!     id: i32,
//!     count: i32,
//!     #[ipc(len = "count")]
//!     t1: Vec<T1>,
//!     #[ipc(char)]
//!     grade: u8,
//! }
//!
//! assert_eq!(T1::FORMAT, "{int, {enum : 3}, [double:2,3], double}");
//! assert_eq!(T2::FORMAT, "{int, int, <T1:2>, char}");
//! assert_eq!(T1::TYPE_NAME, "module::T1");
//! ```
//!
//! # Type mapping
//!
//! | Rust field | IPC format |
//! |---|---|
//! | `i8` `u8` `i16` `u16` `i32` `u32` `i64` `u64` `f32` `f64` `bool` | `byte` `ubyte` `short` `ushort` `int` `uint` `long` `ulong` `float` `double` `boolean` |
//! | `#[ipc(char)] u8`, `char` (Latin-1) | `char`: one byte; a `char` above U+00FF is refused by publish, query and reply (`PublishError::Length`, naming the field; `ipc::to_vec` and `cdr::to_vec`, which do not check, send `'?'`); use `#[ipc(char)] u8` for exact bytes |
//! | `String`, `Option<String>` | `string`: `None` goes out as C's NULL string, and `Some("")` arrives as `None` (NULL and `""` are the same bytes in IPC; CDR does the same, so both backends agree) |
//! | `[[T; m]; n]` | `[T:n,m]` |
//! | `#[ipc(len = "count")] Vec<T>` | `<T:k>`, k = 1-based index of field `count` |
//! | `Vec<T>` without `len` | a DDS `sequence<T>` (CDR only): its IPC format `<T:0>` names no count field, so an IPC session refuses the type when it is first used (`OpenError`, naming the type, its format and the `len` attribute to add); fine on `rtps://` and XRCE |
//! | `#[ipc(len = "rows, cols")] Matrix<T>`, `#[ipc(len = "a, b, c")] NdVec<T, 3>` | `<T:k1,k2>`, `<T:k1,k2,k3>`: flat, row-major, sized by those fields |
//! | `Option<Box<T>>` | `*T` |
//! | `Option<Box<Self>>` (or the type's own name) | `*!` |
//! | a struct deriving `IpcMessage` | its format name (registered by `named_formats`) |
//! | a fieldless enum deriving `IpcMessage` | `{enum A, B, C}` or `{enum : max}`, inline |
//!
//! `usize`/`isize`, 128-bit integers, references, raw pointers, tuples,
//! slices, maps and sets, `Option<T>` other than the two forms above, `Vec`
//! anywhere but directly as a field, data-carrying enums and unions are
//! compile errors that say what to use instead.
//!
//! # Attributes
//!
//! On the struct or enum:
//!
//! | attribute | meaning |
//! |---|---|
//! | `#[ipc(name = "T1")]` | format name of a struct (default: the Rust identifier) |
//! | `#[ipc(type_name = "HelloWorldData::Msg")]` | DDS type name (default: `module_path!()::Ident`, plus `<params>` for generic types) |
//! | `#[ipc(numeric)]` | enum: `{enum : max}` instead of `{enum A, B, C}`; implied by any explicit discriminant |
//! | `#[ipc(extensibility = "final" \| "appendable" \| "mutable")]` | struct: XTypes extensibility of the CDR encoding (default final) |
//! | `#[ipc(crate = "::courier_wire")]` | path of the wire crate in generated code (default: found in the crate's `Cargo.toml`, see *Crate path* below) |
//!
//! On a field:
//!
//! | attribute | meaning |
//! |---|---|
//! | `#[ipc(len = "count")]` | this `Vec` is `<T:k>`; its length lives in the integer field `count` (one `Vec` per length field; for tuple structs name the index, `len = "0"`); the encoders write `count` from the `Vec`, and a session refuses to send a `Vec` longer than `count`'s type can say ([`PublishError::Length`](crate::PublishError::Length)) rather than send it cut short. C's IPC reads a length field as an `int`: for C peers, make it `i32` or `u32` |
//! | `#[ipc(len = "rows, cols")]` | this [`NdVec`](crate::NdVec) (or [`Matrix`](crate::Matrix)) is `<T:k1,k2,…>`; its shape lives in those `i32`/`u32`/`i64`/`u64` fields, one per dimension, in order |
//! | `#[ipc(char)]` | this `u8` is an IPC `char` |
//! | `#[ipc(key)]` | DDS key field (`KEYS`, `cdr_encode_key`); key members carry the XTypes must-understand flag, as idlc gives `@key` members |
//! | `#[ipc(must_understand)]` | sets the must-understand flag of a non-key member |
//! | `#[ipc(id = 7)]` | CDR member id (mutable structs); ids continue sequentially after it |
//! | `#[ipc(bound = 10)]` | this `String` holds at most 10 bytes, this `Vec` at most 10 elements (IDL `string<10>`, `sequence<T, 10>`; what `courier gen` emits for them): a session refuses to send a longer one ([`PublishError::Length`](crate::PublishError::Length)), and a typed subscriber refuses to take one ([`RecvError::Decode`](crate::RecvError::Decode)), as DDS implementations refuse a bounded value over its bound. In a key it also decides whether the key hash is the key or its MD5 (see *Key hashes* below). The IPC format is unchanged (IPC has no bounds) |
//!
//! # Choices
//!
//! - **Crate path.** Generated code finds the wire crate through the user's
//!   `Cargo.toml` (`proc-macro-crate`): `courier` under the name it is given
//!   there (`courier2 = { package = "courier" }` gives `::courier2::__wire`),
//!   else `courier-wire` under its name, else `::courier::__wire`.
//!   `#[ipc(crate = "::path::to::wire")]` overrides it (a crate that
//!   re-exports `courier` under another path). The lookup reads
//!   `[dev-dependencies]` too: a crate whose library depends on
//!   `courier-wire` and whose tests alone on `courier` says
//!   `#[ipc(crate = "::courier_wire")]`.
//! - **What the derive refuses at compile time** besides unsupported types:
//!   a format `name` (or, for a named struct, its identifier) IPC cannot
//!   read as a format name (a primitive such as `int`, `enum`, a leading
//!   digit, format punctuation); an enum value past `i32::MAX`, implicit
//!   ones included; an empty message (`()`, a unit struct) as a `Vec`,
//!   array or pointer element; `#[ipc(key)]` on an `Option<Box<T>>` (XTypes
//!   keys are never optional); a value given to a flag (`key = true`).
//!   A length field must be written as an integer type by its name
//!   (`u32`, `std::primitive::u32`): the derive sees tokens, not types, and
//!   does not resolve aliases. `r#type` is the member `type`.
//! - **Large fixed arrays.** A `[T; N]` field is a value: decoding builds
//!   it on the stack (several times over in a debug build), and a struct
//!   holding 100 KB of array overflowed tokio's 2 MiB worker stacks. Put a
//!   large one behind a box, `Box<[u8; 1_000_000]>` (or
//!   `Option<Box<[T; N]>>`): the same format and wire bytes, the array's
//!   elements decoded straight into the heap. Only the boxed array is:
//!   in `Box<[[u8; 1 << 20]; 4]>` each inner array is still built on the
//!   stack; box those (`[Box<[u8; 1 << 20]>; 4]`) or use a `Vec`.
//! - **Variable arrays.** On encode the length field is written as the `Vec`'s
//!   length (the field's own value is ignored), in IPC and in CDR, so the data
//!   never disagrees with its count. A `Vec` longer than the length field's type
//!   (or `i32::MAX`) can express is truncated to that many elements. On IPC
//!   decode the length field gets its wire value, and if it precedes the array
//!   the array's wire count must equal it (`DecodeError::CountMismatch`). CDR
//!   decoding takes both values as they come (a DDS peer's count field is just
//!   a field).
//! - **Multi-dimensional variable arrays** (`<T:k1,k2,…>`) are
//!   [`NdVec<T, N>`](crate::NdVec), whose shape and elements always agree
//!   (its constructors check, and no shape holds more than `i32::MAX`
//!   elements): on encode the size fields are written from the shape, so
//!   encoding cannot fail. They must be `i32`, `u32`, `i64` or `u64`, which
//!   hold any dimension (C's IPC reads them as `int`). On decode, in IPC and
//!   in CDR, the shape is the size fields' values and must hold exactly the
//!   elements received (`DecodeError::Shape` otherwise, naming the shape).
//!   In CDR the elements are one flat `sequence<T>` after the size members,
//!   as Cyclone DDS writes IDL `long rows; long cols; sequence<T> cells;`.
//!   An `NdVec` and its size fields cannot be DDS keys.
//!
//!   ```
//!   use courier::{IpcMessage, Matrix};
//!
//!   #[derive(IpcMessage, Debug, PartialEq)]
//!   struct Image {
//!       rows: i32,
//!       cols: i32,
//!       #[ipc(len = "rows, cols")]
//!       pixels: Matrix<u8>,
//!   }
//!
//!   assert_eq!(Image::FORMAT, "{int, int, <ubyte:1,2>}");
//!   let img = Image {
//!       rows: 0, // written from the shape: 2
//!       cols: 0, // and 3
//!       pixels: Matrix::new([2, 3], vec![1, 2, 3, 4, 5, 6])?,
//!   };
//!   let back: Image = courier::ipc::from_slice(&courier::ipc::to_vec(&img))?;
//!   assert_eq!((back.rows, back.cols, back.pixels[[1, 2]]), (2, 3, 6));
//!   # Ok::<(), Box<dyn std::error::Error>>(())
//!   ```
//! - **Unit structs** (and structs without fields) are the empty message:
//!   `FORMAT` is `""` as for `()`, they have no format name, and using one as
//!   a field of another struct fails at compile time.
//! - **Generics.** Type parameters get an `IpcMessage` bound. A generic struct
//!   has one format per instantiation, so it is written inline (no format
//!   name, and `#[ipc(name)]` on it is an error); its default `TYPE_NAME`
//!   lists the type arguments' type names and the const arguments' values
//!   in declaration order (`Buf<4>` and `Buf<8>` are different DDS types).
//!   A generic struct may point to itself (`Option<Box<Self>>` is `*!`),
//!   but two generic structs that point to each other have no finite
//!   format: rustc stops with "cycle detected when simplifying constant …
//!   `FORMAT`". Make one of them non-generic: its format name then ends
//!   the recursion, as between two plain structs.
//!   Lifetime parameters are a compile error.
//! - **Format names** default to the Rust identifier, so two types with the
//!   same identifier in different modules need `#[ipc(name = "...")]` to
//!   register distinct formats.
//! - **Enums** are int32 in IPC and CDR; an unknown value decodes to
//!   `DecodeError::InvalidEnum` naming `TYPE_NAME`.
//! - **CDR.** Members are framed by `cdr::Writer::begin_struct` /
//!   `begin_member`; member ids count from 0. `Option<Box<T>>` members are
//!   `@optional` (`cdr::write_optional`): an absent one is left out of a
//!   mutable struct and decodes to `None`.
//! - **Type evolution** (XTypes). A member the writer's version of a type
//!   does not have — one missing from a mutable struct, or one after the end
//!   of an appendable struct's data (XCDR2: its `DHEADER` says where it ends)
//!   — takes its default: 0, `false`, `""`, empty sequences and `NdVec`s, the
//!   first enumerator, `None`, and for a struct its members' defaults. A
//!   missing key member is `cdr::DecodeError::MissingMember`. Members the
//!   reader's version does not have are skipped (an unknown must-understand
//!   member is `UnknownMustUnderstand`). Final structs, and appendable ones in
//!   XCDR1, do not evolve: the versions must match.
//! - **Keys.** `cdr_encode_key` writes the struct's framing with only the
//!   key members (a key member whose type has no keys is written whole);
//!   `type Key` is what `cdr_decode_key` reads back from it: the one key
//!   field's type (its own `Key`), a tuple of them for several key fields,
//!   and `Self` for a struct without key fields.
//! - **Key hashes.** The key hash of an instance (the `PID_KEY_HASH` of
//!   DDSI-RTPS 2.5 §9.6.4.8) is its key in the key-hash form (big-endian,
//!   every struct final, key members in member-id order; so are the
//!   members of a key member whose struct type has no key fields, all of
//!   them keys, as Cyclone DDS orders them), zero-padded to 16 bytes when
//!   the *type's* largest key fits in 16 bytes, else the MD5 digest of
//!   it, however short the actual key. The derive works the largest key
//!   out at compile time (`IpcMessage::CDR_KEY_MAX_SIZE`, a `cdr::MaxSize`):
//!   an unbounded `String` or `Vec` has no largest, a `#[ipc(bound = N)]`
//!   `String` (IDL `string<N>`) counts as 4 + N + 1 bytes aligned to 4, a
//!   bounded `Vec` at its bound. So `#[ipc(key, bound = 11)] name: String`
//!   alone is padded and `bound = 12` hashed, as idlc and Cyclone DDS 11's
//!   C library decide and Fast DDS's generated code does.
//!
//!   The form exists in both XCDR versions, and the hash of one instance
//!   can differ between them. XCDR2 aligns every member to its size but at
//!   most 4, and puts a `DHEADER` before a sequence or an array of enums,
//!   structs or strings (Cyclone DDS counts only integers, floats,
//!   booleans and chars as primitive elements); XCDR1 aligns to the size up
//!   to 8 and has no `DHEADER`. `#[ipc(key)] a: i32, #[ipc(key)] b: i64`
//!   is 12 bytes in XCDR2 and 16 in XCDR1 (4 of padding before `b`); add
//!   `#[ipc(key)] c: i32` and the XCDR1 key (20 bytes) is hashed with MD5
//!   while the XCDR2 one (16) is padded. `CDR_KEY_MAX_SIZE` measures both
//!   (`max_len_in(Version::Xcdr1)`, idlc's `DDS_TOPIC_FIXED_KEY`, and
//!   `max_len_in(Version::Xcdr2)`, its `DDS_TOPIC_FIXED_KEY_XCDR2`).
//!   Which one applies is the XCDR version of the data: Cyclone DDS and
//!   Fast DDS compute the hash in it, and Courier sends it so, in the
//!   publication's data representation (XCDR1 for a final type unless
//!   [`PublicationQos::data_representation`](crate::PublicationQos::data_representation)
//!   says otherwise, XCDR2 for appendable and mutable types). Take it with
//!   [`key_hash_in`](crate::key_hash_in)`(&v, version)`;
//!   [`key_hash`](crate::key_hash) is the XCDR2 form, the one DDS-XTypes
//!   1.3 §7.6.8 specifies. An appendable or mutable struct has no
//!   `DHEADER` or member headers in either version's form.
//!
//!   Cyclone DDS 0.10's runtime pads by the actual length instead of the
//!   type's largest, and the Python `cyclonedds` 11 binding counts a
//!   bounded string as 4 + N bytes (no NUL); Courier follows the
//!   specification, Cyclone DDS 11's C library and Fast DDS. A struct that
//!   holds itself through a bounded `Vec` counts as unbounded; types that
//!   hold each other through bounded `Vec`s (`A` a `Vec<B>`, `B` a
//!   `Vec<A>`) compile, but a key holding them fails to compile when its
//!   key hash is taken (the size would depend on itself).
//!
//!   ```
//!   use courier::cdr::Version;
//!   use courier::IpcMessage;
//!
//!   #[derive(IpcMessage)]
//!   struct Robot {
//!       #[ipc(key, bound = 8)]
//!       name: String,
//!       x: f64,
//!   }
//!
//!   assert_eq!(Robot::CDR_KEY_MAX_SIZE.max_len(), Some(13));
//!   let r = Robot { name: "ab".into(), x: 0.0 };
//!   // length 3 ("ab" and the NUL), "ab", NUL, then zeros
//!   assert_eq!(courier::key_hash(&r), [0, 0, 0, 3, b'a', b'b', 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
//!
//!   #[derive(IpcMessage)]
//!   struct Stamped {
//!       #[ipc(key)]
//!       id: i32,
//!       #[ipc(key)]
//!       stamp: i64,
//!   }
//!
//!   let s = Stamped { id: 1, stamp: 2 };
//!   // XCDR1: the long long aligned to 8; XCDR2: to 4
//!   assert_eq!(
//!       courier::key_hash_in(&s, Version::Xcdr1),
//!       [0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 2]
//!   );
//!   assert_eq!(
//!       courier::key_hash_in(&s, Version::Xcdr2),
//!       [0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0, 2, 0, 0, 0, 0]
//!   );
//!   ```
