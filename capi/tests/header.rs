//! `include/kin.h` is written by hand: every status code the library returns must be defined
//! there with the same value, or a C caller would misread a failure.

use kin_capi::*;

/// The value `#define NAME value` gives in the header, if it defines it.
fn defined(header: &str, name: &str) -> Option<i32> {
    header.lines().find_map(|line| {
        let mut words = line.split_whitespace();
        if words.next() == Some("#define") && words.next() == Some(name) {
            words.next()?.parse().ok()
        } else {
            None
        }
    })
}

#[test]
fn the_header_defines_every_status_code_with_the_librarys_value() {
    let header = include_str!("../include/kin.h");
    let codes = [
        ("KIN_OK", KIN_OK),
        ("KIN_ERR_POINTER", KIN_ERR_POINTER),
        ("KIN_ERR_SIZE", KIN_ERR_SIZE),
        ("KIN_ERR_UTF8", KIN_ERR_UTF8),
        ("KIN_ERR_COMPILE", KIN_ERR_COMPILE),
        ("KIN_ERR_PARAMS", KIN_ERR_PARAMS),
        ("KIN_ERR_EVAL", KIN_ERR_EVAL),
        ("KIN_ERR_IO", KIN_ERR_IO),
        ("KIN_ERR_INDEX", KIN_ERR_INDEX),
        ("KIN_ERR_PANIC", KIN_ERR_PANIC),
        ("KIN_ERR_VALUE", KIN_ERR_VALUE),
        ("KIN_ERR_OVERLAP", KIN_ERR_OVERLAP),
        ("KIN_ERR_RANGE", KIN_ERR_RANGE),
        ("KIN_ERR_MACHINE", KIN_ERR_MACHINE),
        ("KIN_ERR_DIVERGES", KIN_ERR_DIVERGES),
    ];
    for (name, value) in codes {
        assert_eq!(defined(header, name), Some(value), "{name}");
    }
    // No two codes share a value.
    let mut values: Vec<i32> = codes.iter().map(|(_, v)| *v).collect();
    values.sort_unstable();
    values.dedup();
    assert_eq!(values.len(), codes.len());
}
