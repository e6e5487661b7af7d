//! Which implementation of the exact march [`Lidar::scan`](super::Lidar::scan) runs.
//!
//! Every path performs the same IEEE operations lane by lane (no FMA), so all give the
//! same bits on the same input (tested on random grids and on real race tracks). By
//! default a scan takes the widest path the CPU supports, detected at run time; benches,
//! tests and `paddock perf` force a narrower one with [`Lidar::with_path`] to measure what
//! CPUs without AVX-512 (or without AVX) get.
//!
//! [`Lidar::with_path`]: super::Lidar::with_path

use std::fmt;

/// A code path of the exact scan.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum ScanPath {
    /// Plain Rust, any CPU: one ray per operation (the compiler's SSE2 on x86-64).
    Portable,
    /// x86-64 with AVX: four rays per instruction (the widest path of AVX2-only CPUs such
    /// as AMD Zen 1-3 and most Intel desktop parts).
    Avx,
    /// x86-64 with AVX-512F and AVX2: eight rays per instruction, two packets stepped
    /// together.
    Avx512,
}

/// A path was asked for that this CPU cannot run.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("scan path `{path}` needs CPU features this CPU lacks (it has: {features})")]
pub struct ScanPathError {
    pub path: ScanPath,
    /// The SIMD features this CPU has, as [`cpu_features`] lists them.
    pub features: String,
}

impl ScanPath {
    /// Every path, narrowest first.
    pub const ALL: [ScanPath; 3] = [ScanPath::Portable, ScanPath::Avx, ScanPath::Avx512];

    /// The path's name: `portable`, `avx` or `avx512`.
    pub fn name(self) -> &'static str {
        match self {
            ScanPath::Portable => "portable",
            ScanPath::Avx => "avx",
            ScanPath::Avx512 => "avx512",
        }
    }

    /// The path named `name` (as [`ScanPath::name`] spells it).
    pub fn from_name(name: &str) -> Option<ScanPath> {
        ScanPath::ALL.into_iter().find(|p| p.name() == name)
    }

    /// Whether this CPU can run the path.
    pub fn supported(self) -> bool {
        match self {
            ScanPath::Portable => true,
            #[cfg(target_arch = "x86_64")]
            ScanPath::Avx => std::arch::is_x86_feature_detected!("avx"),
            #[cfg(target_arch = "x86_64")]
            ScanPath::Avx512 => {
                std::arch::is_x86_feature_detected!("avx512f")
                    && std::arch::is_x86_feature_detected!("avx2")
            }
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    /// The widest path this CPU supports (what a scan uses unless told otherwise).
    pub fn best() -> ScanPath {
        ScanPath::ALL
            .into_iter()
            .rev()
            .find(|p| p.supported())
            .unwrap_or(ScanPath::Portable)
    }

    /// How the march reads its clearance table on this CPU: `gather` (the `avx` path on
    /// Intel CPUs with AVX2: one AVX2 gather per step of four rays) or `scalar loads`
    /// (every other case). Both read the same bytes; only the speed differs.
    pub fn clearance_loads(self) -> &'static str {
        #[cfg(target_arch = "x86_64")]
        if self == ScanPath::Avx && super::march::avx_gather_pays() {
            return "gather";
        }
        "scalar loads"
    }

    /// The vectors of the angular sweep's per-beam loops on this path here: `256-bit` on
    /// `avx`, and on `avx512` where the CPU is Intel's (see [`sweep_in_256_bits`]),
    /// `512-bit` on `avx512` elsewhere, `none` on the portable path. The crossings
    /// themselves are 256-bit kernels on both SIMD paths, and every way gives the same
    /// bits; only the speed differs.
    pub fn sweep_vectors(self) -> &'static str {
        match self {
            ScanPath::Portable => "none",
            ScanPath::Avx => "256-bit",
            ScanPath::Avx512 if sweep_in_256_bits() => "256-bit",
            ScanPath::Avx512 => "512-bit",
        }
    }

    /// The SIMD level the march takes (0 portable, 1 AVX, 2 AVX-512).
    pub(super) fn level(self) -> u8 {
        match self {
            ScanPath::Portable => 0,
            ScanPath::Avx => 1,
            ScanPath::Avx512 => 2,
        }
    }
}

impl fmt::Display for ScanPath {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The SIMD features of this CPU that matter to the scan, space-separated (for example
/// `sse2 avx avx2 fma avx512f`), or `none detected`.
pub fn cpu_features() -> String {
    #[cfg(target_arch = "x86_64")]
    {
        let mut have = Vec::new();
        macro_rules! probe {
            ($($f:tt),*) => {
                $(if std::arch::is_x86_feature_detected!($f) {
                    have.push($f);
                })*
            };
        }
        probe!(
            "sse2", "sse4.1", "avx", "avx2", "fma", "avx512f", "avx512dq", "avx512vl"
        );
        if !have.is_empty() {
            return have.join(" ");
        }
    }
    "none detected".to_string()
}

/// Whether the `avx512` path runs the angular sweep compiled for AVX (256-bit vectors)
/// rather than for AVX-512: on Intel CPUs, where code compiled for AVX-512 runs the
/// sweep's per-beam loops in 512-bit vectors, whose frequency licence costs more than they
/// save there (one car's step 11-13 % faster in 256-bit vectors on an Intel Xeon, family 6
/// model 167; 3-8 % slower on an AMD Zen 4, whose 512-bit operations cost no licence:
/// docs/performance-scan.md). The march keeps its AVX-512 kernels either way.
pub(in crate::lidar) fn sweep_in_256_bits() -> bool {
    #[cfg(test)]
    if let Some(forced) = SWEEP_IN_256_BITS.get() {
        return forced;
    }
    #[cfg(target_arch = "x86_64")]
    return intel();
    #[cfg(not(target_arch = "x86_64"))]
    false
}

/// Whether this CPU is Intel's (CPUID's vendor string), read once: the choices that
/// differ between Intel and AMD CPUs ask this.
#[cfg(target_arch = "x86_64")]
pub(in crate::lidar) fn intel() -> bool {
    static INTEL: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *INTEL.get_or_init(|| cpu_vendor() == "GenuineIntel")
}

#[cfg(test)]
thread_local! {
    /// Tests: [`sweep_in_256_bits`]'s answer on this thread, where set.
    pub(in crate::lidar) static SWEEP_IN_256_BITS: std::cell::Cell<Option<bool>> =
        const { std::cell::Cell::new(None) };
}

/// The vendor string of CPUID leaf 0 (`GenuineIntel`, `AuthenticAMD`, ...).
#[cfg(target_arch = "x86_64")]
pub(in crate::lidar) fn cpu_vendor() -> String {
    let id = std::arch::x86_64::__cpuid(0);
    let bytes: Vec<u8> = [id.ebx, id.edx, id.ecx]
        .iter()
        .flat_map(|r| r.to_le_bytes())
        .collect();
    String::from_utf8_lossy(&bytes)
        .trim_matches('\0')
        .to_string()
}

/// This CPU as it names itself, so that a figure says where it was measured: on x86-64
/// its brand string, vendor, family and model as CPUID gives them (for example `AMD EPYC
/// (AuthenticAMD, family 25 model 1)`; a virtual machine's brand string is often
/// shortened, the family and model are the host's); elsewhere the architecture.
pub fn cpu_model() -> String {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::__cpuid;
        let text = |regs: &[u32]| {
            let bytes: Vec<u8> = regs.iter().flat_map(|r| r.to_le_bytes()).collect();
            let text = String::from_utf8_lossy(&bytes).replace('\0', " ");
            text.split_whitespace().collect::<Vec<_>>().join(" ")
        };
        let vendor = cpu_vendor();
        let sig = __cpuid(1).eax;
        let (base_family, base_model) = ((sig >> 8) & 0xf, (sig >> 4) & 0xf);
        let family = if base_family == 0xf {
            base_family + ((sig >> 20) & 0xff)
        } else {
            base_family
        };
        let model = if base_family == 0x6 || base_family == 0xf {
            ((sig >> 16) & 0xf) << 4 | base_model
        } else {
            base_model
        };
        let brand = if __cpuid(0x8000_0000).eax >= 0x8000_0004 {
            let regs: Vec<u32> = (0x8000_0002..=0x8000_0004)
                .flat_map(|leaf| {
                    let r = __cpuid(leaf);
                    [r.eax, r.ebx, r.ecx, r.edx]
                })
                .collect();
            text(&regs)
        } else {
            String::new()
        };
        let brand = if brand.is_empty() { "x86-64" } else { &brand };
        format!("{brand} ({vendor}, family {family} model {model})")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        std::env::consts::ARCH.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cpu_names_itself() {
        let model = cpu_model();
        assert!(!model.trim().is_empty());
        assert!(!model.contains('\0'), "{model:?}");
        #[cfg(target_arch = "x86_64")]
        {
            // "<brand> (<vendor>, family F model M)", F and M numbers
            let (_, inner) = model.rsplit_once(" (").expect(&model);
            let (_, numbers) = inner.split_once(", family ").expect(&model);
            let (family, rest) = numbers.split_once(" model ").expect(&model);
            let model_no = rest.strip_suffix(')').expect(&model);
            assert!(family.parse::<u32>().is_ok_and(|f| f >= 5), "{model}");
            assert!(model_no.parse::<u32>().is_ok(), "{model}");
        }
    }
}
