//! The maps the project ships, compiled into the library.
//!
//! Shipped maps are bytes inside the binary (`build.rs` embeds every file of every folder
//! in the project's `maps/`), so a binary finds them wherever it is installed or copied,
//! and never through the source tree it was compiled from. They load straight from those
//! bytes ([`crate::circuit::Circuit::shipped`]): nothing is written anywhere. This table
//! is constant data; which maps a program uses, and how long it keeps them, is up to the
//! [`crate::circuit::Circuits`] registry it creates.

/// One shipped map: its folder name and its files (bare names and contents), sorted by
/// file name.
#[derive(Debug)]
pub struct ShippedMap {
    pub name: &'static str,
    pub files: &'static [(&'static str, &'static [u8])],
}

impl ShippedMap {
    /// The contents of the file called `name` (a bare file name).
    pub fn file(&self, name: &str) -> Option<&'static [u8]> {
        self.files.iter().find(|(n, _)| *n == name).map(|(_, d)| *d)
    }
}

include!(concat!(env!("OUT_DIR"), "/shipped_maps.rs"));

/// Every shipped map, sorted by name.
pub fn shipped_maps() -> &'static [ShippedMap] {
    SHIPPED_MAPS
}

/// The shipped map called `name` (case-insensitive).
pub fn shipped_map(name: &str) -> Option<&'static ShippedMap> {
    SHIPPED_MAPS
        .iter()
        .find(|m| m.name.eq_ignore_ascii_case(name))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_case_insensitive() {
        assert!(shipped_maps().len() >= 3);
        assert_eq!(shipped_map("QUARRY").map(|m| m.name), Some("quarry"));
        assert!(shipped_map("no-such-map").is_none());
    }

    #[test]
    fn files_by_name() {
        let m = shipped_map("lakeside").expect("lakeside ships");
        assert!(m.file("lakeside_map.yaml").is_some_and(|d| !d.is_empty()));
        assert!(m.file("../lakeside_map.yaml").is_none());
    }
}
