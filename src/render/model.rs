//! Triangle models with glTF 2.0 metallic-roughness materials, loaded from
//! `.gltf`/`.glb` files or built procedurally.
//!
//! Loading flattens the default scene: every mesh primitive of every node is
//! transformed to world space (positions by the node's global matrix, normals by
//! its inverse transpose, tangents by its upper 3x3, winding reversed where the
//! determinant is negative, as the glTF spec requires). Accessors are read by our
//! own bounds-checked reader, so a hostile file yields an [`Error`] naming it,
//! never a panic or an unbounded allocation: [`LoadLimits`] caps triangles,
//! vertices, node visits and texture sizes.

use crate::error::{Error, Result};
use crate::image::io::Limits;
use glam::{Mat3, Mat4, Vec2, Vec3, Vec4};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// How texture coordinates outside `[0, 1]` are mapped (glTF sampler wrap modes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum WrapMode {
    /// Tile (glTF default, `REPEAT`).
    #[default]
    Repeat,
    /// Tile with every other copy mirrored (`MIRRORED_REPEAT`).
    MirroredRepeat,
    /// Clamp to the edge texel (`CLAMP_TO_EDGE`).
    ClampToEdge,
}

impl WrapMode {
    /// Maps an integer texel index into `[0, n)`.
    #[inline]
    fn apply(self, i: i64, n: usize) -> usize {
        let n = n as i64;
        let r = match self {
            WrapMode::Repeat => i.rem_euclid(n),
            WrapMode::ClampToEdge => i.clamp(0, n - 1),
            WrapMode::MirroredRepeat => {
                let p = i.rem_euclid(2 * n);
                if p < n {
                    p
                } else {
                    2 * n - 1 - p
                }
            }
        };
        r as usize
    }
}

/// An 8-bit RGB texture as stored in the file. Samples are converted to linear
/// floats on lookup (through the sRGB curve for colour textures), before
/// filtering, so filtering happens in linear space.
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    width: usize,
    height: usize,
    data: Vec<u8>,
}

/// sRGB-decoded values of the 256 8-bit codes.
fn srgb_lut() -> &'static [f32; 256] {
    static LUT: OnceLock<[f32; 256]> = OnceLock::new();
    LUT.get_or_init(|| {
        let mut t = [0.0f32; 256];
        for (i, v) in t.iter_mut().enumerate() {
            *v = crate::tonemap::srgb_eotf(i as f32 / 255.0);
        }
        t
    })
}

/// Linear values of the 256 8-bit codes (`code / 255`).
fn linear_lut() -> &'static [f32; 256] {
    static LUT: OnceLock<[f32; 256]> = OnceLock::new();
    LUT.get_or_init(|| {
        let mut t = [0.0f32; 256];
        for (i, v) in t.iter_mut().enumerate() {
            *v = i as f32 / 255.0;
        }
        t
    })
}

impl Texture {
    /// Wraps interleaved 8-bit RGB data; fails if the length does not match.
    pub fn from_rgb8(width: usize, height: usize, data: Vec<u8>) -> Result<Self> {
        if width == 0 || height == 0 || data.len() != width * height * 3 {
            return Err(Error::Invalid(format!(
                "texture of {} bytes does not hold {width}x{height} RGB texels",
                data.len()
            )));
        }
        Ok(Texture {
            width,
            height,
            data,
        })
    }
    /// Width in texels.
    pub fn width(&self) -> usize {
        self.width
    }
    /// Height in texels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Bilinear lookup at glTF texture coordinates (`(0, 0)` is the top-left
    /// corner of the image), decoded to linear RGB; `srgb` selects the sRGB
    /// transfer (baseColor and emissive textures) instead of plain `code / 255`.
    pub fn sample(&self, uv: Vec2, wrap_s: WrapMode, wrap_t: WrapMode, srgb: bool) -> [f32; 3] {
        let lut = if srgb { srgb_lut() } else { linear_lut() };
        let (u, v) = if uv.is_finite() {
            (uv.x, uv.y)
        } else {
            (0.0, 0.0)
        };
        // Keep the coordinate in a range where f32 -> i64 is exact enough.
        let x = (u * self.width as f32 - 0.5).clamp(-1e7, 1e7);
        let y = (v * self.height as f32 - 0.5).clamp(-1e7, 1e7);
        let x0 = x.floor();
        let y0 = y.floor();
        let tx = x - x0;
        let ty = y - y0;
        let xa = wrap_s.apply(x0 as i64, self.width);
        let xb = wrap_s.apply(x0 as i64 + 1, self.width);
        let ya = wrap_t.apply(y0 as i64, self.height);
        let yb = wrap_t.apply(y0 as i64 + 1, self.height);
        let texel =
            |x: usize, y: usize, k: usize| lut[self.data[3 * (y * self.width + x) + k] as usize];
        let mut out = [0.0; 3];
        for (k, o) in out.iter_mut().enumerate() {
            let top = texel(xa, ya, k) * (1.0 - tx) + texel(xb, ya, k) * tx;
            let bot = texel(xa, yb, k) * (1.0 - tx) + texel(xb, yb, k) * tx;
            *o = top * (1.0 - ty) + bot * ty;
        }
        out
    }
}

/// A material's use of a texture: which texture, which UV set, which wrapping.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TextureRef {
    /// Index into [`Model::textures`].
    pub texture: usize,
    /// UV set (`TEXCOORD_n`); 0 and 1 are supported, others fall back to 0.
    pub tex_coord: u32,
    /// Horizontal wrap mode.
    pub wrap_s: WrapMode,
    /// Vertical wrap mode.
    pub wrap_t: WrapMode,
}

impl TextureRef {
    /// A reference to `texture` through UV set 0 with repeat wrapping.
    pub fn new(texture: usize) -> Self {
        TextureRef {
            texture,
            tex_coord: 0,
            wrap_s: WrapMode::Repeat,
            wrap_t: WrapMode::Repeat,
        }
    }
}

/// A glTF 2.0 metallic-roughness material (core spec section 3.9 plus the
/// emissive-strength and specular-factor extensions).
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    /// Name from the file, if any (for messages).
    pub name: Option<String>,
    /// Linear RGBA base colour factor (alpha is kept but not rendered).
    pub base_color: [f32; 4],
    /// sRGB-encoded base colour texture, multiplied with the factor.
    pub base_color_texture: Option<TextureRef>,
    /// Metalness factor.
    pub metallic: f32,
    /// Perceptual roughness factor.
    pub roughness: f32,
    /// Linear texture: G multiplies roughness, B multiplies metallic.
    pub metallic_roughness_texture: Option<TextureRef>,
    /// Tangent-space normal map (linear, `2 t - 1`).
    pub normal_texture: Option<TextureRef>,
    /// Scale of the normal map's X and Y.
    pub normal_scale: f32,
    /// Ambient occlusion texture (R channel, linear).
    pub occlusion_texture: Option<TextureRef>,
    /// `ao = 1 + strength (R - 1)`.
    pub occlusion_strength: f32,
    /// Linear emissive factor.
    pub emissive: [f32; 3],
    /// sRGB-encoded emissive texture, multiplied with the factor.
    pub emissive_texture: Option<TextureRef>,
    /// KHR_materials_emissive_strength multiplier (1 without the extension).
    pub emissive_strength: f32,
    /// KHR_materials_specular `specularFactor` (1 without the extension): weight
    /// of the dielectric specular layer; 0 makes a dielectric purely Lambertian.
    pub specular: f32,
    /// Both faces are drawn and the back face is lit with a reversed normal.
    pub double_sided: bool,
}

impl Default for Material {
    /// The glTF default material: white, metallic 1, roughness 1, single-sided.
    fn default() -> Self {
        Material {
            name: None,
            base_color: [1.0; 4],
            base_color_texture: None,
            metallic: 1.0,
            roughness: 1.0,
            metallic_roughness_texture: None,
            normal_texture: None,
            normal_scale: 1.0,
            occlusion_texture: None,
            occlusion_strength: 1.0,
            emissive: [0.0; 3],
            emissive_texture: None,
            emissive_strength: 1.0,
            specular: 1.0,
            double_sided: false,
        }
    }
}

impl Material {
    /// An untextured material with the given base colour, metalness and roughness.
    pub fn basic(base_color: [f32; 3], metallic: f32, roughness: f32) -> Self {
        Material {
            base_color: [base_color[0], base_color[1], base_color[2], 1.0],
            metallic,
            roughness,
            ..Default::default()
        }
    }

    fn texture_refs(&self) -> impl Iterator<Item = &TextureRef> {
        [
            &self.base_color_texture,
            &self.metallic_roughness_texture,
            &self.normal_texture,
            &self.occlusion_texture,
            &self.emissive_texture,
        ]
        .into_iter()
        .flatten()
    }
}

/// One triangle list in world space with a single material.
///
/// Attribute vectors are either empty (absent) or as long as `positions`.
/// Missing normals mean flat shading with the geometric normal (glTF's rule);
/// missing tangents with a normal map mean a per-triangle tangent frame from the
/// UV derivatives.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// World-space vertex positions.
    pub positions: Vec<Vec3>,
    /// Unit world-space normals, or empty.
    pub normals: Vec<Vec3>,
    /// World-space tangents with handedness in `w`, or empty.
    pub tangents: Vec<Vec4>,
    /// `TEXCOORD_0`, or empty.
    pub uv0: Vec<Vec2>,
    /// `TEXCOORD_1`, or empty.
    pub uv1: Vec<Vec2>,
    /// Linear `COLOR_0` RGB multiplied into the base colour, or empty.
    pub colors: Vec<Vec3>,
    /// Triangles as vertex indices, counter-clockwise when seen from the front.
    pub indices: Vec<[u32; 3]>,
    /// Index into [`Model::materials`].
    pub material: usize,
}

/// Axis-aligned bounding box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Smallest corner.
    pub min: Vec3,
    /// Largest corner.
    pub max: Vec3,
}

impl Aabb {
    /// The empty box (min = +inf, max = -inf), the identity for [`Aabb::grow`].
    pub fn empty() -> Self {
        Aabb {
            min: Vec3::splat(f32::INFINITY),
            max: Vec3::splat(f32::NEG_INFINITY),
        }
    }
    /// Extends the box to contain `p` (non-finite points are ignored).
    pub fn grow(&mut self, p: Vec3) {
        if p.is_finite() {
            self.min = self.min.min(p);
            self.max = self.max.max(p);
        }
    }
    /// Whether the box contains no point.
    pub fn is_empty(&self) -> bool {
        !(self.min.x <= self.max.x && self.min.y <= self.max.y && self.min.z <= self.max.z)
    }
    /// Centre of the box.
    pub fn center(&self) -> Vec3 {
        0.5 * (self.min + self.max)
    }
    /// Radius of the sphere around [`Aabb::center`] through the corners.
    pub fn radius(&self) -> f32 {
        0.5 * (self.max - self.min).length()
    }
}

/// Resource caps applied while loading untrusted model files.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LoadLimits {
    /// Most triangles in the whole flattened scene.
    pub max_triangles: usize,
    /// Most vertices read from one accessor.
    pub max_accessor_elements: usize,
    /// Longest texture side in texels.
    pub max_texture_side: usize,
    /// Most texels summed over all decoded textures.
    pub max_total_texels: u64,
    /// Most node visits while walking the scene graph (guards against shared or
    /// cyclic subtrees blowing up).
    pub max_node_visits: usize,
}

impl Default for LoadLimits {
    /// 20M triangles, 60M elements per accessor, 16384-texel sides, 2^29 texels
    /// in total (1.5 GiB as RGB8), 1M node visits.
    fn default() -> Self {
        LoadLimits {
            max_triangles: 20_000_000,
            max_accessor_elements: 60_000_000,
            max_texture_side: 16_384,
            max_total_texels: 1 << 29,
            max_node_visits: 1_000_000,
        }
    }
}

/// A renderable scene: meshes in world space, their materials and textures.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Model {
    /// Triangle lists in world space.
    pub meshes: Vec<Mesh>,
    /// Materials referenced by [`Mesh::material`].
    pub materials: Vec<Material>,
    /// Textures referenced by [`TextureRef::texture`].
    pub textures: Vec<Texture>,
}

impl Model {
    /// Loads the default scene of a `.gltf` or `.glb` file with default limits.
    pub fn load(path: &Path) -> Result<Model> {
        Model::load_with(path, &LoadLimits::default())
    }

    /// Loads the default scene of a `.gltf` or `.glb` file; external buffers and
    /// images are resolved relative to the file's folder.
    pub fn load_with(path: &Path, limits: &LoadLimits) -> Result<Model> {
        let bytes = crate::fsutil::read(path)?;
        let base = path.parent().unwrap_or(Path::new("."));
        Model::from_slice(&bytes, Some(base), path, limits)
    }

    /// Loads a glTF/GLB held in memory. `base` is the folder for relative URIs
    /// (`None` allows only embedded data); `name` is used in error messages.
    pub fn from_slice(
        bytes: &[u8],
        base: Option<&Path>,
        name: &Path,
        limits: &LoadLimits,
    ) -> Result<Model> {
        crate::image::io::guard_panic(name, "glTF", || load_gltf(bytes, base, name, limits))
    }

    /// A UV sphere centred at the origin: `segments` longitudinal slices and
    /// `segments / 2` latitude bands (at least 3 and 2), smooth normals, tangents
    /// along increasing longitude, `u` around and `v` from the north pole down.
    /// Used by the tests as a surface with analytic normals.
    pub fn uv_sphere(radius: f32, segments: usize, material: Material) -> Model {
        let nlon = segments.max(3);
        let nlat = (segments / 2).max(2);
        let mut mesh = Mesh::default();
        for j in 0..=nlat {
            let v = j as f32 / nlat as f32;
            let theta = v * std::f32::consts::PI; // from +y
            let (st, ct) = theta.sin_cos();
            for i in 0..=nlon {
                let u = i as f32 / nlon as f32;
                let phi = u * 2.0 * std::f32::consts::PI;
                let (sp, cp) = phi.sin_cos();
                // Longitude runs from +z towards +x.
                let n = Vec3::new(st * sp, ct, st * cp);
                mesh.positions.push(n * radius);
                mesh.normals.push(n);
                mesh.tangents.push(Vec4::new(cp, 0.0, -sp, 1.0));
                mesh.uv0.push(Vec2::new(u, v));
            }
        }
        let row = nlon + 1;
        for j in 0..nlat {
            for i in 0..nlon {
                let a = (j * row + i) as u32;
                let b = (j * row + i + 1) as u32;
                let c = ((j + 1) * row + i) as u32;
                let d = ((j + 1) * row + i + 1) as u32;
                // Counter-clockwise seen from outside.
                if j != 0 {
                    mesh.indices.push([a, c, b]);
                }
                if j != nlat - 1 {
                    mesh.indices.push([b, c, d]);
                }
            }
        }
        mesh.material = 0;
        Model {
            meshes: vec![mesh],
            materials: vec![material],
            textures: Vec::new(),
        }
    }

    /// Bounding box of all vertices referenced by a triangle.
    pub fn bounds(&self) -> Aabb {
        let mut b = Aabb::empty();
        for m in &self.meshes {
            for t in &m.indices {
                for &i in t {
                    if let Some(p) = m.positions.get(i as usize) {
                        b.grow(*p);
                    }
                }
            }
        }
        b
    }

    /// Total number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.meshes.iter().map(|m| m.indices.len()).sum()
    }

    /// Checks internal consistency (index, attribute-length, material and
    /// texture references) so the renderer can index without panicking; a
    /// model built by hand is checked the same way as a loaded one.
    pub fn validate(&self) -> Result<()> {
        for t in &self.textures {
            if t.width == 0 || t.height == 0 || t.data.len() != t.width * t.height * 3 {
                return Err(Error::Invalid("model has a malformed texture".into()));
            }
        }
        for (k, mat) in self.materials.iter().enumerate() {
            for r in mat.texture_refs() {
                if r.texture >= self.textures.len() {
                    return Err(Error::Invalid(format!(
                        "material {k} references texture {} of {}",
                        r.texture,
                        self.textures.len()
                    )));
                }
            }
        }
        for (k, m) in self.meshes.iter().enumerate() {
            let n = m.positions.len();
            if n > u32::MAX as usize {
                return Err(Error::limit(
                    None,
                    format!("mesh {k}: {n} vertices"),
                    format!("{} vertices", u32::MAX),
                ));
            }
            let ok = |len: usize| len == 0 || len == n;
            if !ok(m.normals.len())
                || !ok(m.tangents.len())
                || !ok(m.uv0.len())
                || !ok(m.uv1.len())
                || !ok(m.colors.len())
            {
                return Err(Error::Invalid(format!(
                    "mesh {k}: attribute lengths do not match its {n} positions"
                )));
            }
            if m.material >= self.materials.len() {
                return Err(Error::Invalid(format!(
                    "mesh {k} references material {} of {}",
                    m.material,
                    self.materials.len()
                )));
            }
            if let Some(bad) = m.indices.iter().flatten().find(|&&i| i as usize >= n) {
                return Err(Error::Invalid(format!(
                    "mesh {k}: vertex index {bad} out of range for {n} vertices"
                )));
            }
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------
// glTF loading
// ---------------------------------------------------------------------------

struct Loader<'a> {
    name: &'a Path,
    base: Option<&'a Path>,
    limits: &'a LoadLimits,
    buffers: Vec<Vec<u8>>,
    /// glTF image index -> our texture index, decoded on first use.
    image_map: Vec<Option<usize>>,
    textures: Vec<Texture>,
    texels: u64,
}

fn load_gltf(bytes: &[u8], base: Option<&Path>, name: &Path, limits: &LoadLimits) -> Result<Model> {
    let gltf = gltf::Gltf::from_slice_without_validation(bytes)
        .map_err(|e| Error::format(name, format!("not a valid glTF 2.0 / GLB file: {e}")))?;
    validate_json(gltf.document.as_json(), name)?;
    let doc = &gltf.document;
    let mut blob = gltf.blob.clone();
    let mut buffers = Vec::new();
    for b in doc.buffers() {
        let data = match b.source() {
            gltf::buffer::Source::Bin => blob.take().ok_or_else(|| {
                Error::format(
                    name,
                    format!("buffer {} refers to a missing GLB BIN chunk", b.index()),
                )
            })?,
            gltf::buffer::Source::Uri(uri) => {
                let max = b.length() as u64 + 4;
                read_uri(uri, base, name, max, &format!("buffer {}", b.index()))?
            }
        };
        if data.len() < b.length() {
            return Err(Error::format(
                name,
                format!(
                    "buffer {} holds {} bytes but declares {}",
                    b.index(),
                    data.len(),
                    b.length()
                ),
            ));
        }
        buffers.push(data);
    }
    let mut ld = Loader {
        name,
        base,
        limits,
        buffers,
        image_map: vec![None; doc.images().count()],
        textures: Vec::new(),
        texels: 0,
    };

    let mut materials = Vec::new();
    for m in doc.materials() {
        materials.push(ld.material(&m)?);
    }
    let default_material = materials.len();
    let mut use_default = false;

    // Roots: the default scene, else the first scene, else all parentless nodes.
    let roots: Vec<gltf::Node> = match doc.default_scene().or_else(|| doc.scenes().next()) {
        Some(s) => s.nodes().collect(),
        None => {
            let mut is_child = vec![false; doc.nodes().count()];
            for n in doc.nodes() {
                for c in n.children() {
                    if let Some(f) = is_child.get_mut(c.index()) {
                        *f = true;
                    }
                }
            }
            doc.nodes().filter(|n| !is_child[n.index()]).collect()
        }
    };

    let mut meshes = Vec::new();
    let mut triangles = 0usize;
    let mut visits = 0usize;
    let mut stack: Vec<(gltf::Node, Mat4, usize)> = roots
        .into_iter()
        .rev()
        .map(|n| (n, Mat4::IDENTITY, 0))
        .collect();
    while let Some((node, parent, depth)) = stack.pop() {
        visits += 1;
        if visits > limits.max_node_visits || depth > 4096 {
            return Err(Error::limit(
                Some(name),
                "the scene graph (too large, or cyclic: a node is its own ancestor)",
                format!("{} node visits or depth 4096", limits.max_node_visits),
            ));
        }
        let local = Mat4::from_cols_array_2d(&node.transform().matrix());
        let world = parent * local;
        if let Some(mesh) = node.mesh() {
            for prim in mesh.primitives() {
                if let Some(mut m) = ld.primitive(&prim, mesh.index(), world)? {
                    triangles = triangles.saturating_add(m.indices.len());
                    if triangles > limits.max_triangles {
                        return Err(Error::limit(
                            Some(name),
                            format!("{triangles} triangles"),
                            format!("{} triangles", limits.max_triangles),
                        ));
                    }
                    match prim.material().index() {
                        Some(i) if i < default_material => m.material = i,
                        _ => {
                            m.material = default_material;
                            use_default = true;
                        }
                    }
                    meshes.push(m);
                }
            }
        }
        for c in node.children().collect::<Vec<_>>().into_iter().rev() {
            stack.push((c, world, depth + 1));
        }
    }
    if use_default {
        materials.push(Material::default());
    }
    let model = Model {
        meshes,
        materials,
        textures: ld.textures,
    };
    model
        .validate()
        .map_err(|e| Error::format(name, e.to_string()))?;
    Ok(model)
}

/// The glTF crate's reference and value validation (every index in range, so
/// its accessors cannot panic), tolerating only the commonly omitted POSITION
/// `min`/`max`, which the loader does not use.
fn validate_json(root: &gltf::json::Root, name: &Path) -> Result<()> {
    use gltf::json::validation::{Error as VErr, Validate};
    // gltf-json's primitive check indexes the accessor list with the POSITION
    // index before that index is range-checked, and panics when it is out of
    // range; so every attribute's accessor is checked here first.
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            for (semantic, acc) in &prim.attributes {
                if acc.value() >= root.accessors.len() {
                    return Err(Error::format(
                        name,
                        format!(
                            "invalid glTF: meshes[{m}].primitives[{p}] attribute {} refers \
                             to accessor {}, but the file has {} accessors",
                            semantic.to_string(),
                            acc.value(),
                            root.accessors.len()
                        ),
                    ));
                }
            }
        }
    }
    let mut errors: Vec<(gltf::json::Path, VErr)> = Vec::new();
    root.validate(root, gltf::json::Path::new, &mut |path, e| {
        errors.push((path(), e))
    });
    errors.retain(|(p, e)| {
        !(matches!(e, VErr::Missing)
            && (p.as_str().ends_with(".min") || p.as_str().ends_with(".max")))
    });
    if errors.is_empty() {
        return Ok(());
    }
    let shown: Vec<String> = errors
        .iter()
        .take(5)
        .map(|(p, e)| format!("{p}: {e}"))
        .collect();
    Err(Error::format(
        name,
        format!(
            "invalid glTF ({} problems): {}",
            errors.len(),
            shown.join("; ")
        ),
    ))
}

/// Decodes standard base64 (padding optional, whitespace ignored).
fn decode_base64(s: &str) -> Option<Vec<u8>> {
    let mut out = Vec::with_capacity(s.len() / 4 * 3 + 3);
    let mut acc = 0u32;
    let mut bits = 0u32;
    for c in s.bytes() {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            b'=' => break,
            b' ' | b'\n' | b'\r' | b'\t' => continue,
            _ => return None,
        };
        acc = (acc << 6) | v as u32;
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    Some(out)
}

/// Resolves a buffer or image URI: a `data:` URI (base64) or a relative file
/// path inside the model's folder tree. Absolute paths, other schemes and
/// files larger than `max_bytes` are refused.
fn read_uri(
    uri: &str,
    base: Option<&Path>,
    name: &Path,
    max_bytes: u64,
    what: &str,
) -> Result<Vec<u8>> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let (_, payload) = rest.split_once(";base64,").ok_or_else(|| {
            Error::format(name, format!("{what}: only base64 data URIs are supported"))
        })?;
        if payload.len() as u64 / 4 * 3 > max_bytes.saturating_add(3) {
            return Err(Error::format(
                name,
                format!("{what}: data URI larger than allowed"),
            ));
        }
        return decode_base64(payload)
            .ok_or_else(|| Error::format(name, format!("{what}: malformed base64 data URI")));
    }
    if uri.contains("://") {
        return Err(Error::unsupported(
            Some(name),
            format!(
                "{what}: {uri:?} is not a file: only files beside the model and data URIs are read"
            ),
        ));
    }
    let rel = crate::fsutil::percent_decode(uri)
        .ok_or_else(|| Error::format(name, format!("{what}: malformed URI {uri:?}")))?;
    let rel_path = Path::new(&rel);
    if rel_path.is_absolute()
        || rel_path.components().any(|c| {
            !matches!(
                c,
                std::path::Component::Normal(_) | std::path::Component::CurDir
            )
        })
    {
        return Err(Error::format(
            name,
            format!("{what}: URI {uri:?} leaves the model's folder; only relative paths below it are read"),
        ));
    }
    let base = base.ok_or_else(|| {
        Error::format(
            name,
            format!("{what}: external file {uri:?} but no base folder given"),
        )
    })?;
    let file: PathBuf = base.join(rel_path);
    let meta = std::fs::metadata(&file).map_err(|e| Error::io(&file, e))?;
    if !meta.is_file() || meta.len() > max_bytes {
        return Err(Error::format(
            &file,
            format!(
                "{what} of {} is not a regular file within the size limit",
                name.display()
            ),
        ));
    }
    crate::fsutil::read(&file)
}

/// Component types of accessors.
#[derive(Clone, Copy)]
enum Comp {
    I8,
    U8,
    I16,
    U16,
    U32,
    F32,
}

impl Comp {
    fn of(d: gltf::accessor::DataType) -> Comp {
        use gltf::accessor::DataType as D;
        match d {
            D::I8 => Comp::I8,
            D::U8 => Comp::U8,
            D::I16 => Comp::I16,
            D::U16 => Comp::U16,
            D::U32 => Comp::U32,
            D::F32 => Comp::F32,
        }
    }
    fn size(self) -> usize {
        match self {
            Comp::I8 | Comp::U8 => 1,
            Comp::I16 | Comp::U16 => 2,
            Comp::U32 | Comp::F32 => 4,
        }
    }
    /// Value as f64, normalised to [0, 1] / [-1, 1] when `norm` (glTF 3.11).
    #[inline]
    fn read(self, b: &[u8], norm: bool) -> f64 {
        match self {
            Comp::I8 => {
                let v = b[0] as i8 as f64;
                if norm {
                    (v / 127.0).max(-1.0)
                } else {
                    v
                }
            }
            Comp::U8 => {
                let v = b[0] as f64;
                if norm {
                    v / 255.0
                } else {
                    v
                }
            }
            Comp::I16 => {
                let v = i16::from_le_bytes([b[0], b[1]]) as f64;
                if norm {
                    (v / 32767.0).max(-1.0)
                } else {
                    v
                }
            }
            Comp::U16 => {
                let v = u16::from_le_bytes([b[0], b[1]]) as f64;
                if norm {
                    v / 65535.0
                } else {
                    v
                }
            }
            Comp::U32 => {
                let v = u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64;
                if norm {
                    v / 4_294_967_295.0
                } else {
                    v
                }
            }
            Comp::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        }
    }
}

impl Loader<'_> {
    fn err(&self, msg: String) -> Error {
        Error::format(self.name, msg)
    }

    /// Bytes `[offset + i * stride, ... + elem)` of a buffer view, bounds-checked
    /// against the view and its buffer. Returns the view's byte slice.
    fn view_bytes(&self, view: &gltf::buffer::View, what: &str) -> Result<&[u8]> {
        let buf = self
            .buffers
            .get(view.buffer().index())
            .ok_or_else(|| self.err(format!("{what}: buffer {} missing", view.buffer().index())))?;
        let start = view.offset();
        let end = start
            .checked_add(view.length())
            .filter(|&e| e <= buf.len())
            .ok_or_else(|| {
                self.err(format!(
                    "{what}: buffer view {} ({} bytes at {}) exceeds its buffer of {} bytes",
                    view.index(),
                    view.length(),
                    start,
                    buf.len()
                ))
            })?;
        Ok(&buf[start..end])
    }

    /// Reads an accessor as `count * dims` f64 values (sparse substitution
    /// applied), checking every range before touching memory.
    fn read_accessor(&self, acc: &gltf::Accessor, what: &str) -> Result<(Vec<f64>, usize)> {
        let dims = acc.dimensions().multiplicity();
        let comp = Comp::of(acc.data_type());
        let norm = acc.normalized();
        let count = acc.count();
        if count > self.limits.max_accessor_elements {
            return Err(self.err(format!(
                "{what}: accessor {} has {count} elements (limit {})",
                acc.index(),
                self.limits.max_accessor_elements
            )));
        }
        let elem = comp.size() * dims;
        let mut out = vec![0.0f64; count * dims];
        let range_err = || {
            self.err(format!(
                "{what}: accessor {} ({count} x {elem} bytes) runs past its buffer view",
                acc.index()
            ))
        };
        if let Some(view) = acc.view() {
            let data = self.view_bytes(&view, what)?;
            let stride = view.stride().unwrap_or(elem).max(elem);
            if count > 0 {
                let last = (count - 1)
                    .checked_mul(stride)
                    .and_then(|x| x.checked_add(acc.offset()))
                    .and_then(|x| x.checked_add(elem))
                    .ok_or_else(range_err)?;
                if last > data.len() {
                    return Err(range_err());
                }
            }
            for i in 0..count {
                let at = acc.offset() + i * stride;
                for k in 0..dims {
                    let o = at + k * comp.size();
                    out[i * dims + k] = comp.read(&data[o..o + comp.size()], norm);
                }
            }
        }
        if let Some(sparse) = acc.sparse() {
            let n = sparse.count();
            if n > count {
                return Err(self.err(format!(
                    "{what}: sparse accessor {} has {n} substitutions for {count} elements",
                    acc.index()
                )));
            }
            let iv = sparse.indices();
            let icomp = match iv.index_type() {
                gltf::accessor::sparse::IndexType::U8 => Comp::U8,
                gltf::accessor::sparse::IndexType::U16 => Comp::U16,
                gltf::accessor::sparse::IndexType::U32 => Comp::U32,
            };
            let idata = self.view_bytes(&iv.view(), what)?;
            let vdata = self.view_bytes(&sparse.values().view(), what)?;
            let ineed = iv
                .offset()
                .checked_add(n.checked_mul(icomp.size()).ok_or_else(range_err)?);
            let vneed = sparse
                .values()
                .offset()
                .checked_add(n.checked_mul(elem).ok_or_else(range_err)?);
            if ineed.map_or(true, |e| e > idata.len()) || vneed.map_or(true, |e| e > vdata.len()) {
                return Err(range_err());
            }
            for s in 0..n {
                let io = iv.offset() + s * icomp.size();
                let target = icomp.read(&idata[io..io + icomp.size()], false) as usize;
                if target >= count {
                    return Err(self.err(format!(
                        "{what}: sparse index {target} out of range for {count} elements"
                    )));
                }
                let vo = sparse.values().offset() + s * elem;
                for k in 0..dims {
                    let o = vo + k * comp.size();
                    out[target * dims + k] = comp.read(&vdata[o..o + comp.size()], norm);
                }
            }
        }
        Ok((out, dims))
    }

    /// Reads an accessor with at least `min_dims` components per element as
    /// `N`-vectors (the first `N` components).
    fn read_vecs<const N: usize>(
        &self,
        acc: &gltf::Accessor,
        min_dims: usize,
        what: &str,
    ) -> Result<Vec<[f32; N]>> {
        let (v, dims) = self.read_accessor(acc, what)?;
        if dims < min_dims || dims < N {
            return Err(self.err(format!(
                "{what}: accessor {} has {dims} components, expected {min_dims}",
                acc.index()
            )));
        }
        Ok(v.chunks_exact(dims)
            .map(|c| {
                let mut a = [0.0f32; N];
                for (o, x) in a.iter_mut().zip(c) {
                    *o = *x as f32;
                }
                a
            })
            .collect())
    }

    fn texture_ref(&mut self, tex: gltf::Texture, tex_coord: u32) -> Result<TextureRef> {
        let wrap = |w: gltf::texture::WrappingMode| match w {
            gltf::texture::WrappingMode::ClampToEdge => WrapMode::ClampToEdge,
            gltf::texture::WrappingMode::MirroredRepeat => WrapMode::MirroredRepeat,
            gltf::texture::WrappingMode::Repeat => WrapMode::Repeat,
        };
        let sampler = tex.sampler();
        let index = self.image(tex.source())?;
        Ok(TextureRef {
            texture: index,
            tex_coord,
            wrap_s: wrap(sampler.wrap_s()),
            wrap_t: wrap(sampler.wrap_t()),
        })
    }

    /// Decodes a glTF image (PNG or JPEG, embedded or external) once.
    fn image(&mut self, img: gltf::Image) -> Result<usize> {
        let idx = img.index();
        if let Some(Some(t)) = self.image_map.get(idx) {
            return Ok(*t);
        }
        let label = format!("image {idx}");
        let bytes: Vec<u8> = match img.source() {
            gltf::image::Source::View { view, .. } => self.view_bytes(&view, &label)?.to_vec(),
            gltf::image::Source::Uri { uri, .. } => {
                // Compressed images are far smaller than 4 bytes per texel.
                let max = self.limits.max_total_texels.saturating_mul(4);
                read_uri(uri, self.base, self.name, max, &label)?
            }
        };
        let remaining = self.limits.max_total_texels.saturating_sub(self.texels);
        let side = self.limits.max_texture_side as u64;
        let limits = Limits {
            max_pixels: remaining.min(side.saturating_mul(side)),
        };
        let err_name = PathBuf::from(format!("{} [{label}]", self.name.display()));
        let sdr = crate::image::io::decode_sdr(&bytes, &err_name, &limits)?;
        if sdr.width() > self.limits.max_texture_side || sdr.height() > self.limits.max_texture_side
        {
            return Err(self.err(format!(
                "{label} of {}x{} exceeds the texture side limit {}",
                sdr.width(),
                sdr.height(),
                self.limits.max_texture_side
            )));
        }
        self.texels += (sdr.width() * sdr.height()) as u64;
        let tex = Texture::from_rgb8(sdr.width(), sdr.height(), sdr.data().to_vec())
            .map_err(|e| self.err(format!("{label}: {e}")))?;
        self.textures.push(tex);
        let t = self.textures.len() - 1;
        if let Some(slot) = self.image_map.get_mut(idx) {
            *slot = Some(t);
        }
        Ok(t)
    }

    fn material(&mut self, m: &gltf::Material) -> Result<Material> {
        let pbr = m.pbr_metallic_roughness();
        let mut out = Material {
            name: m.name().map(str::to_owned),
            base_color: pbr.base_color_factor(),
            metallic: pbr.metallic_factor(),
            roughness: pbr.roughness_factor(),
            emissive: m.emissive_factor(),
            emissive_strength: m.emissive_strength().unwrap_or(1.0),
            specular: m.specular().map(|s| s.specular_factor()).unwrap_or(1.0),
            double_sided: m.double_sided(),
            ..Default::default()
        };
        if let Some(t) = pbr.base_color_texture() {
            out.base_color_texture = Some(self.texture_ref(t.texture(), t.tex_coord())?);
        }
        if let Some(t) = pbr.metallic_roughness_texture() {
            out.metallic_roughness_texture = Some(self.texture_ref(t.texture(), t.tex_coord())?);
        }
        if let Some(t) = m.normal_texture() {
            out.normal_scale = t.scale();
            out.normal_texture = Some(self.texture_ref(t.texture(), t.tex_coord())?);
        }
        if let Some(t) = m.occlusion_texture() {
            out.occlusion_strength = t.strength();
            out.occlusion_texture = Some(self.texture_ref(t.texture(), t.tex_coord())?);
        }
        if let Some(t) = m.emissive_texture() {
            out.emissive_texture = Some(self.texture_ref(t.texture(), t.tex_coord())?);
        }
        let finite = out
            .base_color
            .iter()
            .chain(&out.emissive)
            .all(|v| v.is_finite())
            && [
                out.metallic,
                out.roughness,
                out.normal_scale,
                out.occlusion_strength,
                out.emissive_strength,
                out.specular,
            ]
            .iter()
            .all(|v| v.is_finite());
        if !finite {
            return Err(self.err(format!("material {:?} has non-finite factors", m.index())));
        }
        Ok(out)
    }

    /// Reads one primitive into a world-space mesh; `None` for non-triangle
    /// modes (points, lines) and primitives without positions.
    fn primitive(
        &mut self,
        prim: &gltf::Primitive,
        mesh_index: usize,
        world: Mat4,
    ) -> Result<Option<Mesh>> {
        use gltf::mesh::Mode;
        use gltf::Semantic;
        let mode = prim.mode();
        if !matches!(
            mode,
            Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
        ) {
            return Ok(None);
        }
        let what = format!("mesh {mesh_index} primitive {}", prim.index());
        let Some(pos_acc) = prim.get(&Semantic::Positions) else {
            return Ok(None);
        };
        let positions: Vec<[f32; 3]> = self.read_vecs(&pos_acc, 3, &what)?;
        let n = positions.len();
        let read_same = |this: &Self, sem: Semantic, min: usize| -> Result<Option<Vec<[f32; 4]>>> {
            match prim.get(&sem) {
                None => Ok(None),
                Some(acc) => {
                    let (v, dims) = this.read_accessor(&acc, &what)?;
                    if dims < min {
                        return Err(this.err(format!("{what}: {sem:?} has {dims} components")));
                    }
                    if v.len() / dims != n {
                        return Err(this.err(format!(
                            "{what}: {sem:?} has {} elements but POSITION has {n}",
                            v.len() / dims
                        )));
                    }
                    Ok(Some(
                        v.chunks_exact(dims)
                            .map(|c| {
                                let mut a = [1.0f32; 4];
                                for (o, x) in a.iter_mut().zip(c) {
                                    *o = *x as f32;
                                }
                                a
                            })
                            .collect(),
                    ))
                }
            }
        };
        let normals = read_same(self, Semantic::Normals, 3)?;
        let tangents = read_same(self, Semantic::Tangents, 4)?;
        let uv0 = read_same(self, Semantic::TexCoords(0), 2)?;
        let uv1 = read_same(self, Semantic::TexCoords(1), 2)?;
        let colors = read_same(self, Semantic::Colors(0), 3)?;

        // Indices (or implicit 0..n), then assembly by mode.
        let idx: Vec<u32> = match prim.indices() {
            Some(acc) => {
                let (v, dims) = self.read_accessor(&acc, &what)?;
                if dims != 1 {
                    return Err(self.err(format!("{what}: index accessor is not scalar")));
                }
                let mut out = Vec::with_capacity(v.len());
                for x in v {
                    if !(x >= 0.0 && (x as usize) < n) {
                        return Err(self.err(format!(
                            "{what}: vertex index {x} out of range for {n} vertices"
                        )));
                    }
                    out.push(x as u32);
                }
                out
            }
            None => {
                if n > u32::MAX as usize {
                    return Err(self.err(format!("{what}: too many vertices")));
                }
                (0..n as u32).collect()
            }
        };
        let mut tris: Vec<[u32; 3]> = match mode {
            Mode::Triangles => idx.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
            Mode::TriangleStrip => (2..idx.len())
                .map(|i| {
                    if i % 2 == 0 {
                        [idx[i - 2], idx[i - 1], idx[i]]
                    } else {
                        [idx[i - 1], idx[i - 2], idx[i]]
                    }
                })
                .collect(),
            _ => (2..idx.len())
                .map(|i| [idx[i - 1], idx[i], idx[0]])
                .collect(),
        };
        if tris.len() > self.limits.max_triangles {
            return Err(self.err(format!(
                "{what}: more than {} triangles (limit)",
                self.limits.max_triangles
            )));
        }

        // World transform: normals by the cofactor matrix (inverse transpose up to
        // the sign of the determinant), winding and tangent handedness flipped for
        // mirroring transforms.
        let m3 = Mat3::from_mat4(world);
        let det = m3.determinant();
        let cof = Mat3::from_cols(
            m3.y_axis.cross(m3.z_axis),
            m3.z_axis.cross(m3.x_axis),
            m3.x_axis.cross(m3.y_axis),
        ) * if det < 0.0 { -1.0 } else { 1.0 };
        if det < 0.0 {
            for t in &mut tris {
                t.swap(1, 2);
            }
        }
        let mut mesh = Mesh {
            positions: positions
                .iter()
                .map(|p| world.transform_point3(Vec3::from_array(*p)))
                .collect(),
            indices: tris,
            ..Default::default()
        };
        if let Some(ns) = normals {
            mesh.normals = ns
                .iter()
                .map(|c| (cof * Vec3::new(c[0], c[1], c[2])).normalize_or_zero())
                .collect();
        }
        if let Some(ts) = tangents {
            let s = if det < 0.0 { -1.0 } else { 1.0 };
            mesh.tangents = ts
                .iter()
                .map(|c| {
                    let t = (m3 * Vec3::new(c[0], c[1], c[2])).normalize_or_zero();
                    let w = if c[3] < 0.0 { -s } else { s };
                    t.extend(w)
                })
                .collect();
        }
        if let Some(u) = uv0 {
            mesh.uv0 = u.iter().map(|c| Vec2::new(c[0], c[1])).collect();
        }
        if let Some(u) = uv1 {
            mesh.uv1 = u.iter().map(|c| Vec2::new(c[0], c[1])).collect();
        }
        if let Some(c) = colors {
            mesh.colors = c.iter().map(|c| Vec3::new(c[0], c[1], c[2])).collect();
        }
        Ok(Some(mesh))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_and_percent_decoding() {
        assert_eq!(decode_base64("aGVsbG8=").unwrap(), b"hello");
        assert_eq!(decode_base64("aGVsbG8").unwrap(), b"hello");
        assert!(decode_base64("a*b").is_none());
        assert_eq!(
            crate::fsutil::percent_decode("a%20b.bin").unwrap(),
            "a b.bin"
        );
        assert!(crate::fsutil::percent_decode("a%2").is_none());
    }

    #[test]
    fn texture_origin_is_top_left_and_srgb_decodes() {
        // 2x2: top row red, green; bottom row blue, 50% grey.
        let t =
            Texture::from_rgb8(2, 2, vec![255, 0, 0, 0, 255, 0, 0, 0, 255, 128, 128, 128]).unwrap();
        let c = WrapMode::ClampToEdge;
        assert_eq!(
            t.sample(Vec2::new(0.25, 0.25), c, c, false),
            [1.0, 0.0, 0.0]
        );
        assert_eq!(
            t.sample(Vec2::new(0.75, 0.25), c, c, false),
            [0.0, 1.0, 0.0]
        );
        assert_eq!(
            t.sample(Vec2::new(0.25, 0.75), c, c, false),
            [0.0, 0.0, 1.0]
        );
        let g = t.sample(Vec2::new(0.75, 0.75), c, c, true)[0];
        assert!((g - 0.2158).abs() < 1e-3, "{g}");
        // Bilinear halfway between red and green.
        let m = t.sample(Vec2::new(0.5, 0.25), c, c, false);
        assert!((m[0] - 0.5).abs() < 1e-6 && (m[1] - 0.5).abs() < 1e-6);
        // Repeat wraps.
        let r = WrapMode::Repeat;
        assert_eq!(
            t.sample(Vec2::new(1.25, -0.75), r, r, false),
            [1.0, 0.0, 0.0]
        );
    }

    #[test]
    fn wrap_modes() {
        assert_eq!(WrapMode::Repeat.apply(-1, 4), 3);
        assert_eq!(WrapMode::ClampToEdge.apply(9, 4), 3);
        assert_eq!(WrapMode::MirroredRepeat.apply(4, 4), 3);
        assert_eq!(WrapMode::MirroredRepeat.apply(-1, 4), 0);
    }

    #[test]
    fn sphere_is_valid_and_outward() {
        let m = Model::uv_sphere(2.0, 16, Material::default());
        m.validate().unwrap();
        let mesh = &m.meshes[0];
        for t in &mesh.indices {
            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
            let n = (b - a).cross(c - a);
            assert!(n.dot(a + b + c) > 0.0, "triangle {t:?} faces inward");
        }
        let b = m.bounds();
        assert!((b.radius() - 2.0 * 3f32.sqrt()).abs() < 0.05);
    }

    #[test]
    fn hostile_bytes_are_errors() {
        let name = Path::new("bad.glb");
        let l = LoadLimits::default();
        assert!(Model::from_slice(b"glTF\x02\0\0\0\xff\xff", None, name, &l).is_err());
        assert!(Model::from_slice(b"{\"asset\":", None, name, &l).is_err());
        // Index past the end of a 3-vertex buffer, buffer via data URI.
        let json = r#"{"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],
          "nodes":[{"mesh":0}],"meshes":[{"primitives":[{"attributes":{"POSITION":0},"indices":1}]}],
          "buffers":[{"byteLength":42,"uri":"data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAAAAABAAcA"}],
          "bufferViews":[{"buffer":0,"byteOffset":0,"byteLength":36},{"buffer":0,"byteOffset":36,"byteLength":6}],
          "accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3"},
                       {"bufferView":1,"componentType":5123,"count":3,"type":"SCALAR"}]}"#;
        let e = Model::from_slice(json.as_bytes(), None, name, &l).unwrap_err();
        assert!(e.to_string().contains("out of range"), "{e}");
        assert!(e.to_string().contains("bad.glb"), "{e}");
        // The same with a good index loads.
        let ok = json.replace("AAABAAcA", "AAABAAIA");
        let m = Model::from_slice(ok.as_bytes(), None, name, &l).unwrap();
        assert_eq!(m.triangle_count(), 1);
        assert_eq!(m.materials.len(), 1);
        // An accessor running past its view.
        let bad = ok.replace(
            "\"count\":3,\"type\":\"VEC3\"",
            "\"count\":4,\"type\":\"VEC3\"",
        );
        assert!(Model::from_slice(bad.as_bytes(), None, name, &l).is_err());
    }
}
