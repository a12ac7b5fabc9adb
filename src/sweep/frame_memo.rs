//! The work on a frame set's images that every reference of the set shares (`references`):
//! the census words of each image and its half-size twins for coarse to fine, made once per
//! set and camera whatever the number of references. [`crate::engine::Sweeper::run_references`]
//! opens the memo for a set ([`FrameMemo::begin`]) and closes it after the last reference;
//! outside such a set (a plain `run`) nothing is kept and every run makes its own.
//!
//! Entries are keyed by the camera's name and the image's size (a level of coarse to fine has
//! its own), so within one set a camera's image is the same bytes whichever reference's rig
//! holds it ([`FrameMemo::begin`] refuses rigs whose names repeat).

use std::collections::HashMap;

use crate::image::Rgba8Image;

type Key = (String, u32, u32);

/// Census words and half-size images of the current frame set, per camera and level.
#[derive(Debug, Default)]
pub struct FrameMemo {
    active: bool,
    census: HashMap<Key, Vec<u32>>,
    halves: HashMap<Key, Rgba8Image>,
    /// Census transforms made and reused since the memo was opened (for tests and logs).
    pub made: usize,
    pub reused: usize,
}

impl FrameMemo {
    /// Opens the memo for one frame set of cameras `names`; a set whose names repeat is not
    /// memoised (returns false).
    pub fn begin<'a>(&mut self, names: impl IntoIterator<Item = &'a str>) -> bool {
        self.end();
        let mut seen = std::collections::HashSet::new();
        self.active = names.into_iter().all(|n| seen.insert(n));
        self.active
    }

    /// Closes the memo: its entries go.
    pub fn end(&mut self) {
        self.active = false;
        self.census.clear();
        self.halves.clear();
        self.made = 0;
        self.reused = 0;
    }

    pub fn is_active(&self) -> bool {
        self.active
    }

    /// Appends the census words of camera `name`'s `image` to `out`: from the memo when this
    /// set already made them.
    pub fn census_into(&mut self, name: &str, image: &Rgba8Image, out: &mut Vec<u32>) {
        let (width, height) = (image.width as usize, image.height as usize);
        if !self.active {
            super::census::transform(width, height, &image.pixels, out);
            return;
        }
        let key = (name.to_string(), image.width, image.height);
        match self.census.get(&key) {
            Some(words) => {
                out.extend_from_slice(words);
                self.reused += 1;
            }
            None => {
                let mut words = Vec::with_capacity(width * height);
                super::census::transform(width, height, &image.pixels, &mut words);
                out.extend_from_slice(&words);
                self.census.insert(key, words);
                self.made += 1;
            }
        }
    }

    /// The half-size image of camera `name`'s `image` (`make` makes it): from the memo when
    /// this set already made it.
    pub fn half(
        &mut self,
        name: &str,
        image: &Rgba8Image,
        make: impl Fn(&Rgba8Image) -> Rgba8Image,
    ) -> Rgba8Image {
        if !self.active {
            return make(image);
        }
        self.halves
            .entry((name.to_string(), image.width, image.height))
            .or_insert_with(|| make(image))
            .clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn census_is_made_once_per_camera_and_size_while_open() {
        let image = Rgba8Image {
            width: 8,
            height: 4,
            pixels: (0..32u32).map(|i| i * 0x0101_0101 % 0xffff_ffff).collect(),
        };
        let mut plain = Vec::new();
        super::super::census::transform(8, 4, &image.pixels, &mut plain);
        let mut memo = FrameMemo::default();
        let mut out = Vec::new();
        memo.census_into("a", &image, &mut out);
        assert_eq!(out, plain);
        assert_eq!((memo.made, memo.reused), (0, 0), "closed: nothing kept");
        assert!(memo.begin(["a", "b"]));
        for _ in 0..3 {
            let mut out = vec![7];
            memo.census_into("a", &image, &mut out);
            assert_eq!(out[1..], plain[..]);
        }
        assert_eq!((memo.made, memo.reused), (1, 2));
        memo.end();
        assert!(!memo.begin(["a", "a"]), "repeated names are not memoised");
        assert!(!memo.is_active());
    }
}
