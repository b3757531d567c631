use courier_derive::IpcMessage;

// `{enum AVeryLong..., ...}` is written inline in `Holder`'s format, which
// goes over the 1024 bytes a compile-time format holds
#[derive(IpcMessage)]
enum Big {
    AVeryLongVariantNameNumber00,
    AVeryLongVariantNameNumber01,
    AVeryLongVariantNameNumber02,
    AVeryLongVariantNameNumber03,
    AVeryLongVariantNameNumber04,
    AVeryLongVariantNameNumber05,
    AVeryLongVariantNameNumber06,
    AVeryLongVariantNameNumber07,
    AVeryLongVariantNameNumber08,
    AVeryLongVariantNameNumber09,
    AVeryLongVariantNameNumber10,
    AVeryLongVariantNameNumber11,
    AVeryLongVariantNameNumber12,
    AVeryLongVariantNameNumber13,
    AVeryLongVariantNameNumber14,
    AVeryLongVariantNameNumber15,
    AVeryLongVariantNameNumber16,
    AVeryLongVariantNameNumber17,
    AVeryLongVariantNameNumber18,
    AVeryLongVariantNameNumber19,
    AVeryLongVariantNameNumber20,
    AVeryLongVariantNameNumber21,
    AVeryLongVariantNameNumber22,
    AVeryLongVariantNameNumber23,
    AVeryLongVariantNameNumber24,
    AVeryLongVariantNameNumber25,
    AVeryLongVariantNameNumber26,
    AVeryLongVariantNameNumber27,
    AVeryLongVariantNameNumber28,
    AVeryLongVariantNameNumber29,
    AVeryLongVariantNameNumber30,
    AVeryLongVariantNameNumber31,
    AVeryLongVariantNameNumber32,
    AVeryLongVariantNameNumber33,
    AVeryLongVariantNameNumber34,
    AVeryLongVariantNameNumber35,
}

#[derive(IpcMessage)]
struct Holder {
    e: Big,
    x: i32,
}

const _: &str = <Holder as courier_wire::IpcMessage>::FORMAT;

fn main() {}
