//! Content-addressed bytes held in memory while something needs them: the scenarios of
//! the batches and job rounds in flight, which workers fetch by hash (once per worker,
//! then cached there). The broker never decodes them.
//!
//! Every holder (a batch or a round) takes a reference for each distinct blob it uses
//! and releases it when it finishes; a blob without references is dropped. The bytes
//! held are bounded ([`BlobLimits`]): an addition over the bound is refused, so a client
//! cannot make the broker hold unbounded scenario data.

use std::collections::HashMap;

/// Bounds of the blobs held.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BlobLimits {
    /// Bytes of all blobs together.
    pub max_bytes: usize,
}

impl Default for BlobLimits {
    /// 256 MiB (a scenario is a few hundred bytes, a few KB with vehicle YAML).
    fn default() -> Self {
        Self {
            max_bytes: 256 << 20,
        }
    }
}

/// An addition refused because the bound would be exceeded.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("holding {asked} more bytes of scenarios would exceed the limit of {limit} (held: {held})")]
pub struct BlobsFull {
    pub held: usize,
    pub asked: usize,
    pub limit: usize,
}

#[derive(Debug)]
struct Entry<B> {
    blob: B,
    len: usize,
    refs: u32,
}

/// See the module documentation.
#[derive(Debug)]
pub struct Blobs<B> {
    blobs: HashMap<String, Entry<B>>,
    bytes: usize,
    limits: BlobLimits,
}

impl<B> Blobs<B> {
    pub fn new(limits: BlobLimits) -> Self {
        Self {
            blobs: HashMap::new(),
            bytes: 0,
            limits,
        }
    }

    /// Takes a reference on each blob of `add` (hash, blob, its length), storing those not
    /// held yet; all or none: when the new ones would exceed the bound, nothing changes.
    pub fn take(&mut self, add: Vec<(String, B, usize)>) -> Result<(), BlobsFull> {
        let mut new_bytes = 0usize;
        let mut seen = std::collections::HashSet::new();
        for (hash, _, len) in &add {
            if !self.blobs.contains_key(hash) && seen.insert(hash.as_str()) {
                new_bytes += len;
            }
        }
        if self.bytes + new_bytes > self.limits.max_bytes {
            return Err(BlobsFull {
                held: self.bytes,
                asked: new_bytes,
                limit: self.limits.max_bytes,
            });
        }
        for (hash, blob, len) in add {
            match self.blobs.get_mut(&hash) {
                Some(e) => e.refs += 1,
                None => {
                    self.bytes += len;
                    self.blobs.insert(hash, Entry { blob, len, refs: 1 });
                }
            }
        }
        Ok(())
    }

    /// Releases one reference on each of `hashes`; a blob without references is dropped.
    pub fn release<'a>(&mut self, hashes: impl IntoIterator<Item = &'a String>) {
        for hash in hashes {
            if let Some(e) = self.blobs.get_mut(hash) {
                e.refs -= 1;
                if e.refs == 0 {
                    self.bytes -= e.len;
                    self.blobs.remove(hash);
                }
            }
        }
    }

    pub fn get(&self, hash: &str) -> Option<&B> {
        self.blobs.get(hash).map(|e| &e.blob)
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.bytes
    }

    pub fn len(&self) -> usize {
        self.blobs.len()
    }

    pub fn is_empty(&self) -> bool {
        self.blobs.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn blob(h: &str, len: usize) -> (String, Vec<u8>, usize) {
        (h.into(), vec![0; len], len)
    }

    #[test]
    fn blobs_live_while_a_holder_needs_them() {
        let mut b = Blobs::new(BlobLimits { max_bytes: 100 });
        b.take(vec![blob("a", 10), blob("b", 20)]).unwrap();
        b.take(vec![blob("a", 10)]).unwrap();
        assert_eq!((b.len(), b.bytes()), (2, 30));
        b.release(&["a".to_string(), "b".to_string()]);
        assert_eq!((b.len(), b.bytes()), (1, 10), "a is still needed");
        assert!(b.get("a").is_some() && b.get("b").is_none());
        b.release(&["a".to_string()]);
        assert!(b.is_empty());
        assert_eq!(b.bytes(), 0);
        // releasing what is not held is harmless
        b.release(&["zz".to_string()]);
    }

    #[test]
    fn past_the_bound_nothing_is_taken() {
        let mut b = Blobs::new(BlobLimits { max_bytes: 50 });
        b.take(vec![blob("a", 30)]).unwrap();
        let e = b
            .take(vec![blob("a", 30), blob("c", 15), blob("d", 10)])
            .unwrap_err();
        assert_eq!((e.held, e.asked, e.limit), (30, 25, 50));
        assert_eq!((b.len(), b.bytes()), (1, 30), "all or none");
        // one already held costs nothing more
        b.take(vec![blob("a", 30), blob("c", 20)]).unwrap();
        assert_eq!(b.bytes(), 50);
    }
}
