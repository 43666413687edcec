//! Model files: named tensors in safetensors format plus per-object JSON configs in the
//! safetensors header metadata, so one file can hold several MLPs and PCA heads.
//!
//! Layout written by [`Mlp::write`] with prefix `p` (e.g. `mlp.correction`):
//!
//! ```text
//! metadata  p                      JSON {"kind":"panoman.mlp","version":1,"sizes":[…],"activation":"relu"}
//! tensor    p.layer{l}.weight      F32 [out, in]   (row-major = PyTorch nn.Linear layout)
//! tensor    p.layer{l}.bias        F32 [out]
//! tensor    p.input_mean / p.input_scale     F32 [in]
//! tensor    p.output_mean / p.output_scale   F32 [out]
//! ```
//!
//! [`PcaHead::write`]: metadata `p` = `{"kind":"panoman.pca_head","version":1,"dim":D,"rank":r}`,
//! tensors `p.mean` F32 `[D]`, `p.weights` F32 `[D]`, `p.components` F32 `[r, D]` (row k =
//! basis column k), `p.component_variance` F64 `[r]`, `p.total_variance` F64 `[1]`.
//! Values are stored little-endian and copied bit for bit; loading validates the config, every
//! shape, dtype and value, and names the offending tensor in a [`ModelError::Format`].

use std::borrow::Cow;
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use faer::Mat;
use safetensors::tensor::{Dtype, SafeTensors, View};
use serde::{Deserialize, Serialize};

use super::net::Mlp;
use super::pca_head::PcaHead;
use crate::error::{ModelError, Result};

/// Element data of a [`Tensor`].
#[derive(Clone, Debug, PartialEq)]
pub enum TensorData {
    /// 32-bit floats.
    F32(Vec<f32>),
    /// 64-bit floats.
    F64(Vec<f64>),
    /// 32-bit unsigned integers (indices).
    U32(Vec<u32>),
    /// 64-bit signed integers.
    I64(Vec<i64>),
    /// Bytes (opaque blobs, e.g. the serialized LBS rig of a model).
    U8(Vec<u8>),
}

/// Element types a [`TensorStore`] can hand out as typed slices.
pub trait Element: Copy + std::fmt::Debug {
    /// safetensors dtype name.
    const DTYPE: &'static str;
    /// The elements if `data` holds this type.
    fn slice(data: &TensorData) -> Option<&[Self]>;
    /// Whether the value is finite (always true for integers).
    fn is_finite_value(&self) -> bool;
}

macro_rules! element {
    ($t:ty, $variant:ident, $name:literal, $finite:expr) => {
        impl Element for $t {
            const DTYPE: &'static str = $name;
            fn slice(data: &TensorData) -> Option<&[Self]> {
                match data {
                    TensorData::$variant(v) => Some(v),
                    _ => None,
                }
            }
            fn is_finite_value(&self) -> bool {
                let f: fn(&$t) -> bool = $finite;
                f(self)
            }
        }
    };
}
element!(f32, F32, "F32", |x| x.is_finite());
element!(f64, F64, "F64", |x| x.is_finite());
element!(u32, U32, "U32", |_| true);
element!(i64, I64, "I64", |_| true);
element!(u8, U8, "U8", |_| true);

impl TensorData {
    fn len(&self) -> usize {
        match self {
            Self::F32(v) => v.len(),
            Self::F64(v) => v.len(),
            Self::U32(v) => v.len(),
            Self::I64(v) => v.len(),
            Self::U8(v) => v.len(),
        }
    }

    fn dtype(&self) -> Dtype {
        match self {
            Self::F32(_) => Dtype::F32,
            Self::F64(_) => Dtype::F64,
            Self::U32(_) => Dtype::U32,
            Self::I64(_) => Dtype::I64,
            Self::U8(_) => Dtype::U8,
        }
    }

    fn dtype_name(&self) -> &'static str {
        match self {
            Self::F32(_) => "F32",
            Self::F64(_) => "F64",
            Self::U32(_) => "U32",
            Self::I64(_) => "I64",
            Self::U8(_) => "U8",
        }
    }

    fn le_bytes(&self) -> Vec<u8> {
        match self {
            Self::F32(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            Self::F64(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            Self::U32(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            Self::I64(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            Self::U8(v) => v.clone(),
        }
    }
}

/// A named array: row-major `shape` (safetensors convention) and its elements.
#[derive(Clone, Debug, PartialEq)]
pub struct Tensor {
    /// Dimensions, outermost first (row-major).
    pub shape: Vec<usize>,
    /// Elements in row-major order.
    pub data: TensorData,
}

struct Bytes<'a> {
    dtype: Dtype,
    shape: &'a [usize],
    bytes: Vec<u8>,
}

impl View for Bytes<'_> {
    fn dtype(&self) -> Dtype {
        self.dtype
    }
    fn shape(&self) -> &[usize] {
        self.shape
    }
    fn data(&self) -> Cow<'_, [u8]> {
        Cow::Borrowed(&self.bytes)
    }
    fn data_len(&self) -> usize {
        self.bytes.len()
    }
}

/// An in-memory collection of named tensors and string metadata, read from and written to a
/// safetensors file (Hugging Face format: 8-byte header length, JSON header, raw
/// little-endian data). Names are unique; the metadata map holds one JSON config per stored
/// object. Errors name the file (or `<memory>`) and the tensor.
#[derive(Clone, Debug, PartialEq)]
pub struct TensorStore {
    source: PathBuf,
    tensors: BTreeMap<String, Tensor>,
    metadata: BTreeMap<String, String>,
}

impl Default for TensorStore {
    fn default() -> Self {
        Self::new()
    }
}

impl TensorStore {
    /// An empty store whose errors refer to `<memory>`.
    pub fn new() -> Self {
        Self {
            source: PathBuf::from("<memory>"),
            tensors: BTreeMap::new(),
            metadata: BTreeMap::new(),
        }
    }

    /// The file this store was loaded from (`<memory>` otherwise); used in error messages.
    pub fn source(&self) -> &Path {
        &self.source
    }

    fn format_err(&self, what: String) -> ModelError {
        ModelError::Format {
            path: self.source.clone(),
            what,
        }
    }

    /// Inserts (or replaces) a tensor.
    ///
    /// Errors: [`ModelError::Invalid`] if the element count does not match the shape.
    pub fn insert(
        &mut self,
        name: impl Into<String>,
        shape: Vec<usize>,
        data: TensorData,
    ) -> Result<()> {
        let name = name.into();
        let count: usize = shape.iter().product();
        if count != data.len() {
            return Err(ModelError::Invalid(format!(
                "tensor '{name}': shape {shape:?} holds {count} elements, got {}",
                data.len()
            )));
        }
        self.tensors.insert(name, Tensor { shape, data });
        Ok(())
    }

    /// The tensor called `name`.
    pub fn get(&self, name: &str) -> Option<&Tensor> {
        self.tensors.get(name)
    }

    /// Removes and returns the tensor called `name`.
    pub fn remove(&mut self, name: &str) -> Option<Tensor> {
        self.tensors.remove(name)
    }

    /// Tensor names, sorted.
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.tensors.keys().map(String::as_str)
    }

    /// Sets a metadata entry.
    pub fn set_metadata(&mut self, key: impl Into<String>, value: impl Into<String>) {
        self.metadata.insert(key.into(), value.into());
    }

    /// A metadata entry.
    pub fn metadata(&self, key: &str) -> Option<&str> {
        self.metadata.get(key).map(String::as_str)
    }

    /// The tensor `name` of element type `T` with exactly `shape`, all values finite.
    ///
    /// Errors: [`ModelError::Format`] naming the file and the tensor if it is missing, has
    /// another dtype or shape, or holds a NaN/infinity.
    pub fn tensor<T: Element>(&self, name: &str, shape: &[usize]) -> Result<&[T]> {
        let t = self
            .get(name)
            .ok_or_else(|| self.format_err(format!("missing tensor '{name}'")))?;
        let Some(v) = T::slice(&t.data) else {
            return Err(self.format_err(format!(
                "tensor '{name}' has dtype {}, expected {}",
                t.data.dtype_name(),
                T::DTYPE
            )));
        };
        if t.shape != shape {
            return Err(self.format_err(format!(
                "tensor '{name}' has shape {:?}, expected {shape:?}",
                t.shape
            )));
        }
        if let Some(i) = v.iter().position(|x| !x.is_finite_value()) {
            return Err(self.format_err(format!(
                "tensor '{name}' element {i} is {:?} (not finite)",
                v[i]
            )));
        }
        Ok(v)
    }

    /// [`TensorStore::tensor`] for f32.
    pub fn f32_tensor(&self, name: &str, shape: &[usize]) -> Result<&[f32]> {
        self.tensor(name, shape)
    }

    /// [`TensorStore::tensor`] for f64.
    pub fn f64_tensor(&self, name: &str, shape: &[usize]) -> Result<&[f64]> {
        self.tensor(name, shape)
    }

    /// [`TensorStore::tensor`] for u32 (indices).
    pub fn u32_tensor(&self, name: &str, shape: &[usize]) -> Result<&[u32]> {
        self.tensor(name, shape)
    }

    /// Serializes to safetensors bytes (tensors sorted by name; metadata in the header).
    ///
    /// Errors: [`ModelError::Invalid`] if safetensors rejects the contents.
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        let views: Vec<(String, Bytes<'_>)> = self
            .tensors
            .iter()
            .map(|(name, t)| {
                (
                    name.clone(),
                    Bytes {
                        dtype: t.data.dtype(),
                        shape: &t.shape,
                        bytes: t.data.le_bytes(),
                    },
                )
            })
            .collect();
        let meta: HashMap<String, String> = self
            .metadata
            .iter()
            .map(|(k, v)| (k.clone(), v.clone()))
            .collect();
        let meta = (!meta.is_empty()).then_some(meta);
        let bytes = safetensors::serialize(views, meta)
            .map_err(|e| ModelError::Invalid(format!("safetensors serialization failed: {e}")))?;
        canonical_header(bytes)
    }

    /// Parses safetensors bytes; `source` names the origin in later error messages.
    ///
    /// Errors: [`ModelError::Format`] for a malformed file or an unsupported dtype (supported:
    /// F32, F64, U32, I64, U8).
    pub fn from_bytes(bytes: &[u8], source: impl Into<PathBuf>) -> Result<Self> {
        let mut store = Self::new();
        store.source = source.into();
        let st = SafeTensors::deserialize(bytes)
            .map_err(|e| store.format_err(format!("not a valid safetensors file: {e}")))?;
        let (_, meta) = SafeTensors::read_metadata(bytes)
            .map_err(|e| store.format_err(format!("not a valid safetensors file: {e}")))?;
        if let Some(m) = meta.metadata() {
            store.metadata = m.iter().map(|(k, v)| (k.clone(), v.clone())).collect();
        }
        for (name, view) in st.iter() {
            let raw = view.data();
            let data = match view.dtype() {
                Dtype::F32 => TensorData::F32(
                    raw.chunks_exact(4)
                        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                        .collect(),
                ),
                Dtype::F64 => TensorData::F64(
                    raw.chunks_exact(8)
                        .map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8])))
                        .collect(),
                ),
                Dtype::U32 => TensorData::U32(
                    raw.chunks_exact(4)
                        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                        .collect(),
                ),
                Dtype::I64 => TensorData::I64(
                    raw.chunks_exact(8)
                        .map(|c| i64::from_le_bytes(c.try_into().unwrap_or([0; 8])))
                        .collect(),
                ),
                Dtype::U8 => TensorData::U8(raw.to_vec()),
                other => {
                    return Err(store
                        .format_err(format!("tensor '{name}' has unsupported dtype {other:?}")));
                }
            };
            store.tensors.insert(
                name.to_string(),
                Tensor {
                    shape: view.shape().to_vec(),
                    data,
                },
            );
        }
        Ok(store)
    }

    /// Writes the store to `path` atomically (temporary file in the same directory, then
    /// rename).
    ///
    /// Errors: [`ModelError::Io`] naming the path; [`ModelError::Invalid`] from serialization.
    pub fn save(&self, path: &Path) -> Result<()> {
        let bytes = self.to_bytes()?;
        Ok(panoman_mesh::io::write_bytes_atomically(path, &bytes)?)
    }

    /// Reads a store from a safetensors file.
    ///
    /// Errors: [`ModelError::Io`] or [`ModelError::Format`] naming the path.
    pub fn load(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|source| ModelError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_bytes(&bytes, path)
    }
}

const MLP_KIND: &str = "panoman.mlp";
const PCA_KIND: &str = "panoman.pca_head";
const VERSION: u32 = 1;

#[derive(Serialize, Deserialize)]
struct MlpConfig {
    kind: String,
    version: u32,
    sizes: Vec<usize>,
    activation: String,
}

#[derive(Serialize, Deserialize)]
struct PcaConfig {
    kind: String,
    version: u32,
    dim: usize,
    rank: usize,
}

/// Parses the JSON config `prefix`, checking its `kind` and `version` before the other fields.
fn read_config<T: for<'de> Deserialize<'de>>(
    store: &TensorStore,
    prefix: &str,
    want: &str,
) -> Result<T> {
    let json = store
        .metadata(prefix)
        .ok_or_else(|| store.format_err(format!("no config '{prefix}' in the metadata")))?;
    let invalid =
        |e: serde_json::Error| store.format_err(format!("config '{prefix}' is not valid: {e}"));
    let value: serde_json::Value = serde_json::from_str(json).map_err(invalid)?;
    let kind = value.get("kind").and_then(|v| v.as_str()).unwrap_or("?");
    let version = value.get("version").and_then(|v| v.as_u64()).unwrap_or(0);
    if kind != want || version != u64::from(VERSION) {
        return Err(store.format_err(format!(
            "config '{prefix}' is {kind} v{version}, expected {want} v{VERSION}"
        )));
    }
    serde_json::from_value(value).map_err(invalid)
}

impl Mlp {
    /// Stores this network under `prefix` (tensors `prefix.*` and metadata `prefix`; layout in
    /// the module docs). Weights are written `[out, in]` row-major, bit for bit.
    ///
    /// Errors: [`ModelError::Invalid`] only on an internal shape inconsistency.
    pub fn write(&self, store: &mut TensorStore, prefix: &str) -> Result<()> {
        let cfg = MlpConfig {
            kind: MLP_KIND.into(),
            version: VERSION,
            sizes: self.sizes().to_vec(),
            activation: "relu".into(),
        };
        let json = serde_json::to_string(&cfg)
            .map_err(|e| ModelError::Invalid(format!("MLP config: {e}")))?;
        store.set_metadata(prefix, json);
        for l in 0..self.n_layers() {
            let w = self.weight(l);
            let (o, i) = (w.nrows(), w.ncols());
            let row_major: Vec<f32> = (0..o)
                .flat_map(|r| (0..i).map(move |c| w[(r, c)]))
                .collect();
            store.insert(
                format!("{prefix}.layer{l}.weight"),
                vec![o, i],
                TensorData::F32(row_major),
            )?;
            store.insert(
                format!("{prefix}.layer{l}.bias"),
                vec![o],
                TensorData::F32(self.bias(l).to_vec()),
            )?;
        }
        let (nin, nout) = (self.n_inputs(), self.n_outputs());
        for (name, v, n) in [
            ("input_mean", self.input_mean(), nin),
            ("input_scale", self.input_scale(), nin),
            ("output_mean", self.output_mean(), nout),
            ("output_scale", self.output_scale(), nout),
        ] {
            store.insert(
                format!("{prefix}.{name}"),
                vec![n],
                TensorData::F32(v.to_vec()),
            )?;
        }
        Ok(())
    }

    /// Loads the network stored under `prefix`, validating the config, every tensor's dtype,
    /// shape and finiteness, and that the scales are positive.
    ///
    /// Errors: [`ModelError::Format`] naming the config or tensor that is wrong.
    pub fn read(store: &TensorStore, prefix: &str) -> Result<Self> {
        let cfg: MlpConfig = read_config(store, prefix, MLP_KIND)?;
        if cfg.activation != "relu" {
            return Err(store.format_err(format!(
                "config '{prefix}': unsupported activation '{}'",
                cfg.activation
            )));
        }
        if cfg.sizes.len() < 2 || cfg.sizes.contains(&0) {
            return Err(store.format_err(format!(
                "config '{prefix}': invalid layer sizes {:?}",
                cfg.sizes
            )));
        }
        let sizes = cfg.sizes;
        // Grown tensor by tensor: every size is checked against a stored tensor first.
        let mut params = Vec::new();
        for (l, pair) in sizes.windows(2).enumerate() {
            let (i, o) = (pair[0], pair[1]);
            let w = store.f32_tensor(&format!("{prefix}.layer{l}.weight"), &[o, i])?;
            // Row-major [out, in] → column-major out × in.
            params.extend((0..i).flat_map(|c| (0..o).map(move |r| w[r * i + c])));
            params.extend_from_slice(store.f32_tensor(&format!("{prefix}.layer{l}.bias"), &[o])?);
        }
        let (nin, nout) = (sizes[0], sizes[sizes.len() - 1]);
        let mut norm: [Vec<f32>; 4] = Default::default();
        for (k, (name, n, positive)) in [
            ("input_mean", nin, false),
            ("input_scale", nin, true),
            ("output_mean", nout, false),
            ("output_scale", nout, true),
        ]
        .into_iter()
        .enumerate()
        {
            let full = format!("{prefix}.{name}");
            let v = store.f32_tensor(&full, &[n])?;
            if positive && let Some(i) = v.iter().position(|x| *x <= 0.0) {
                return Err(store.format_err(format!(
                    "tensor '{full}' element {i} is {} (scales must be > 0)",
                    v[i]
                )));
            }
            norm[k] = v.to_vec();
        }
        Ok(Mlp::from_parts(sizes, params, norm))
    }
}

impl PcaHead {
    /// Stores this head under `prefix` (tensors `prefix.*` and metadata `prefix`; layout in the
    /// module docs), bit for bit.
    ///
    /// Errors: [`ModelError::Invalid`] only on an internal shape inconsistency.
    pub fn write(&self, store: &mut TensorStore, prefix: &str) -> Result<()> {
        let (d, r) = (self.dim(), self.rank());
        let cfg = PcaConfig {
            kind: PCA_KIND.into(),
            version: VERSION,
            dim: d,
            rank: r,
        };
        let json = serde_json::to_string(&cfg)
            .map_err(|e| ModelError::Invalid(format!("PCA head config: {e}")))?;
        store.set_metadata(prefix, json);
        store.insert(
            format!("{prefix}.mean"),
            vec![d],
            TensorData::F32(self.mean().to_vec()),
        )?;
        store.insert(
            format!("{prefix}.weights"),
            vec![d],
            TensorData::F32(self.weights().to_vec()),
        )?;
        let p = self.basis();
        let comps: Vec<f32> = (0..r)
            .flat_map(|k| (0..d).map(move |i| p[(i, k)]))
            .collect();
        store.insert(
            format!("{prefix}.components"),
            vec![r, d],
            TensorData::F32(comps),
        )?;
        store.insert(
            format!("{prefix}.component_variance"),
            vec![r],
            TensorData::F64(self.component_variance().to_vec()),
        )?;
        store.insert(
            format!("{prefix}.total_variance"),
            vec![1],
            TensorData::F64(vec![self.total_variance()]),
        )
    }

    /// Loads the head stored under `prefix`, validating the config, shapes, dtypes, finiteness
    /// and positive weights.
    ///
    /// Errors: [`ModelError::Format`] naming the config or tensor that is wrong.
    pub fn read(store: &TensorStore, prefix: &str) -> Result<Self> {
        let cfg: PcaConfig = read_config(store, prefix, PCA_KIND)?;
        let (d, r) = (cfg.dim, cfg.rank);
        if d == 0 || r == 0 || r > d {
            return Err(store.format_err(format!("config '{prefix}': invalid dim {d} / rank {r}")));
        }
        let mean = store.f32_tensor(&format!("{prefix}.mean"), &[d])?.to_vec();
        let wname = format!("{prefix}.weights");
        let weights = store.f32_tensor(&wname, &[d])?.to_vec();
        if let Some(i) = weights.iter().position(|x| *x <= 0.0) {
            return Err(store.format_err(format!(
                "tensor '{wname}' element {i} is {} (weights must be > 0)",
                weights[i]
            )));
        }
        let comps = store.f32_tensor(&format!("{prefix}.components"), &[r, d])?;
        let basis = Mat::<f32>::from_fn(d, r, |i, k| comps[k * d + i]);
        let var = store
            .f64_tensor(&format!("{prefix}.component_variance"), &[r])?
            .to_vec();
        let total = store.f64_tensor(&format!("{prefix}.total_variance"), &[1])?[0];
        Ok(PcaHead::from_parts(mean, weights, basis, var, total))
    }
}

/// Rewrites a safetensors file's JSON header with sorted keys (the crate serializes its
/// metadata from a `HashMap`, whose order changes between processes), padded with spaces to a
/// multiple of 8 bytes as the format requires. The data offsets are unchanged, so the tensors
/// read back identically; equal stores now give byte-identical files.
fn canonical_header(bytes: Vec<u8>) -> Result<Vec<u8>> {
    let bad = |w: &str| ModelError::Invalid(format!("safetensors header: {w}"));
    if bytes.len() < 8 {
        return Err(bad("too short"));
    }
    let n = u64::from_le_bytes(bytes[..8].try_into().expect("8 bytes")) as usize;
    let header = bytes
        .get(8..8 + n)
        .ok_or_else(|| bad("length beyond the data"))?;
    // serde_json's default map is a BTreeMap: parsing and re-serializing sorts every object.
    let value: serde_json::Value =
        serde_json::from_slice(header).map_err(|e| bad(&e.to_string()))?;
    let mut text = serde_json::to_vec(&value).map_err(|e| bad(&e.to_string()))?;
    while text.len() % 8 != 0 {
        text.push(b' ');
    }
    let mut out = Vec::with_capacity(8 + text.len() + bytes.len() - 8 - n);
    out.extend_from_slice(&(text.len() as u64).to_le_bytes());
    out.extend_from_slice(&text);
    out.extend_from_slice(&bytes[8 + n..]);
    Ok(out)
}
