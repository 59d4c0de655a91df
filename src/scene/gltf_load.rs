//! glTF 2.0 (.gltf / .glb) characters: the skinned mesh, its skeleton and animations.
//!
//! The mesh is every triangle primitive of the nodes that use the file's first skin (so a
//! character split into several meshes comes back whole); without a skin, every mesh node,
//! transformed to world space. Texture images are decoded only by [`load_materials`].

use super::Character;
use super::material::{Material, Texture, Wrap};
use super::mesh::{Mesh, MeshData};
use super::rig::{Animation, Channel, Interpolation, Node, Property, Rig, Trs};
use crate::error::{Error, Result};
use glam::{Mat3, Mat4, Quat, Vec3};
use std::path::Path;

pub fn load(path: &Path) -> Result<Character> {
    load_filtered(path, None)
}

/// Only the mesh nodes whose node or mesh name is `name` (case-insensitive), e.g. the
/// `Head` of a character split into several meshes; skinned meshes stay in bind space.
pub fn load_named(path: &Path, name: &str) -> Result<Character> {
    let mut c = load_filtered(path, Some(name))?;
    c.mesh.name = format!("{}:{name}", c.mesh.name);
    Ok(c)
}

/// Several named parts of one character (each chosen as [`load_named`] does), as one mesh:
/// the parts' vertices and triangles concatenated in the order given, and the part index
/// (0, 1, ..) of every triangle. Rig and animations are the file's; the parts must agree on
/// whether they have UVs and skin weights.
pub fn load_parts(path: &Path, names: &[&str]) -> Result<(Character, Vec<u32>)> {
    let Some((first, rest)) = names.split_first() else {
        return Err(Error::input(path, "no part names given"));
    };
    let mut c = load_named(path, first)?;
    let mut parts = vec![0u32; c.mesh.triangles.len()];
    for (i, name) in rest.iter().enumerate() {
        if names[..=i].iter().any(|n| n.eq_ignore_ascii_case(name)) {
            return Err(Error::input(path, format!("part '{name}' given twice")));
        }
        let next = load_named(path, name)?.mesh;
        let m = &mut c.mesh;
        if m.uvs.is_some() != next.uvs.is_some() || m.skin.is_some() != next.skin.is_some() {
            return Err(Error::input(
                path,
                format!("part '{name}' differs from '{first}' in having UVs or skin weights"),
            ));
        }
        let base = m.positions.len() as u32;
        m.positions.extend(&next.positions);
        m.normals.extend(&next.normals);
        if let (Some(a), Some(b)) = (&mut m.uvs, &next.uvs) {
            a.extend(b);
        }
        if let (Some(a), Some(b)) = (&mut m.skin, &next.skin) {
            a.joints.extend(&b.joints);
            a.weights.extend(&b.weights);
        }
        m.triangles
            .extend(next.triangles.iter().map(|t| t.map(|v| v + base)));
        parts.resize(m.triangles.len(), i as u32 + 1);
        let (r, n) = (&mut m.report, &next.report);
        r.vertices += n.vertices;
        r.triangles += n.triangles;
        r.degenerate_triangles_removed += n.degenerate_triangles_removed;
        r.weights_renormalised += n.weights_renormalised;
        r.influences_truncated += n.influences_truncated;
        r.normals_recomputed += n.normals_recomputed;
        r.boundary_edges += n.boundary_edges;
        r.non_manifold_edges += n.non_manifold_edges;
        r.unreferenced_vertices += n.unreferenced_vertices;
    }
    let base = c.mesh.name.split(':').next().unwrap_or("").to_string();
    c.mesh.name = format!("{base}:{}", names.join("+"));
    Ok((c, parts))
}

fn load_filtered(path: &Path, only: Option<&str>) -> Result<Character> {
    let err = |m: String| Error::input(path, m);
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let gltf = gltf::Gltf::from_slice(&bytes).map_err(|e| err(format!("not valid glTF: {e}")))?;
    let doc = gltf.document;
    let base = path.parent();
    let buffers = gltf::import_buffers(&doc, base, gltf.blob)
        .map_err(|e| err(format!("cannot load buffers: {e}")))?;
    let get = |b: gltf::Buffer<'_>| buffers.get(b.index()).map(|d| &d.0[..]);

    // Node hierarchy.
    let mut nodes: Vec<Node> = doc
        .nodes()
        .map(|n| {
            let (t, r, s) = n.transform().decomposed();
            Node {
                name: n.name().unwrap_or("").to_string(),
                parent: None,
                rest: Trs {
                    t: Vec3::from_array(t),
                    r: Quat::from_array(r).normalize(),
                    s: Vec3::from_array(s),
                },
            }
        })
        .collect();
    for n in doc.nodes() {
        for c in n.children() {
            if nodes[c.index()].parent.is_some() {
                return Err(err(format!("node {} has two parents", c.index())));
            }
            nodes[c.index()].parent = Some(n.index());
        }
    }

    let skin = doc.skins().next();
    let mesh_nodes = skin_mesh_nodes(&doc);
    if mesh_nodes.is_empty() {
        return Err(err("no mesh nodes in the scene".into()));
    }
    let mesh_nodes = choose_nodes(mesh_nodes, only).map_err(err)?;

    // Static meshes are flattened into world space; skinned ones stay in bind space.
    let rig_for_world = Rig::new(nodes.clone(), vec![], vec![]).map_err(err)?;
    let world = rig_for_world.globals(&rig_for_world.pose(None, 0.0));

    let mut data = MeshData {
        name: path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default(),
        ..Default::default()
    };
    let mut normals: Vec<[f32; 3]> = Vec::new();
    let mut uvs: Vec<[f32; 2]> = Vec::new();
    let mut influences: Vec<Vec<(u32, f32)>> = Vec::new();
    let (mut all_normals, mut all_uvs) = (true, true);
    for node in &mesh_nodes {
        let mesh = node.mesh().expect("filtered");
        let to_world = if skin.is_some() {
            Mat4::IDENTITY
        } else {
            world[node.index()]
        };
        let normal_matrix = Mat3::from_mat4(to_world).inverse().transpose();
        for (pi, prim) in mesh.primitives().enumerate() {
            let what = format!("mesh '{}' primitive {pi}", mesh.name().unwrap_or(""));
            match prim.mode() {
                gltf::mesh::Mode::Triangles => {}
                m => {
                    return Err(err(format!(
                        "{what}: primitive mode {m:?} is not supported (triangles only)"
                    )));
                }
            }
            let reader = prim.reader(get);
            let pos: Vec<[f32; 3]> = reader
                .read_positions()
                .ok_or_else(|| err(format!("{what} has no POSITION")))?
                .collect();
            let base_index = data.positions.len() as u32;
            let count = pos.len();
            data.positions.extend(
                pos.iter()
                    .map(|p| to_world.transform_point3(Vec3::from_array(*p)).to_array()),
            );
            match reader.read_normals() {
                Some(n) => {
                    normals.extend(n.map(|v| (normal_matrix * Vec3::from_array(v)).to_array()))
                }
                None => all_normals = false,
            }
            match reader.read_tex_coords(0) {
                Some(t) => uvs.extend(t.into_f32()),
                None => all_uvs = false,
            }
            if skin.is_some() {
                let mut inf: Vec<Vec<(u32, f32)>> = vec![Vec::new(); count];
                let mut set = 0;
                while let (Some(j), Some(w)) = (reader.read_joints(set), reader.read_weights(set)) {
                    let j: Vec<[u16; 4]> = j.into_u16().collect();
                    let w: Vec<[f32; 4]> = w.into_f32().collect();
                    if j.len() != count || w.len() != count {
                        return Err(err(format!(
                            "{what}: JOINTS_{set}/WEIGHTS_{set} have {}/{} entries for {count} vertices",
                            j.len(),
                            w.len()
                        )));
                    }
                    for v in 0..count {
                        for k in 0..4 {
                            inf[v].push((j[v][k] as u32, w[v][k]));
                        }
                    }
                    set += 1;
                }
                if set == 0 {
                    return Err(err(format!(
                        "{what} belongs to a skinned node but has no JOINTS_0/WEIGHTS_0"
                    )));
                }
                influences.extend(inf);
            }
            let indices: Vec<u32> = match reader.read_indices() {
                Some(i) => i.into_u32().collect(),
                None => (0..count as u32).collect(),
            };
            if !indices.len().is_multiple_of(3) {
                return Err(err(format!(
                    "{what}: {} indices is not a whole number of triangles",
                    indices.len()
                )));
            }
            for t in indices.chunks_exact(3) {
                if let Some(&bad) = t.iter().find(|&&i| i as usize >= count) {
                    return Err(err(format!(
                        "{what}: index {bad} out of range ({count} vertices)"
                    )));
                }
                data.triangles
                    .push([t[0] + base_index, t[1] + base_index, t[2] + base_index]);
            }
        }
    }
    data.normals = all_normals.then_some(normals);
    data.uvs = all_uvs.then_some(uvs);

    let rig = match &skin {
        Some(s) => {
            let joints: Vec<usize> = s.joints().map(|j| j.index()).collect();
            let ibm: Vec<Mat4> = match s.reader(get).read_inverse_bind_matrices() {
                Some(m) => m.map(|c| Mat4::from_cols_array_2d(&c)).collect(),
                None => vec![Mat4::IDENTITY; joints.len()],
            };
            data.joint_count = joints.len();
            data.influences = Some(influences);
            Rig::new(nodes, joints, ibm).map_err(err)?
        }
        None => Rig::identity(),
    };
    let skinned = skin.is_some();
    let mesh = Mesh::from_data(data, path)?;

    let mut animations = Vec::new();
    if skinned {
        for (ai, anim) in doc.animations().enumerate() {
            let name = anim
                .name()
                .map(str::to_string)
                .unwrap_or_else(|| format!("animation{ai}"));
            let mut channels = Vec::new();
            let mut duration = 0f32;
            for ch in anim.channels() {
                let property = match ch.target().property() {
                    gltf::animation::Property::Translation => Property::Translation,
                    gltf::animation::Property::Rotation => Property::Rotation,
                    gltf::animation::Property::Scale => Property::Scale,
                    gltf::animation::Property::MorphTargetWeights => continue,
                };
                let interpolation = match ch.sampler().interpolation() {
                    gltf::animation::Interpolation::Step => Interpolation::Step,
                    gltf::animation::Interpolation::Linear => Interpolation::Linear,
                    gltf::animation::Interpolation::CubicSpline => Interpolation::CubicSpline,
                };
                let reader = ch.reader(get);
                let times: Vec<f32> = reader
                    .read_inputs()
                    .ok_or_else(|| {
                        err(format!("animation '{name}': a channel has no input times"))
                    })?
                    .collect();
                let values: Vec<[f32; 4]> = match reader.read_outputs() {
                    Some(gltf::animation::util::ReadOutputs::Translations(v)) => {
                        v.map(|[x, y, z]| [x, y, z, 0.0]).collect()
                    }
                    Some(gltf::animation::util::ReadOutputs::Scales(v)) => {
                        v.map(|[x, y, z]| [x, y, z, 0.0]).collect()
                    }
                    Some(gltf::animation::util::ReadOutputs::Rotations(r)) => {
                        r.into_f32().collect()
                    }
                    _ => {
                        return Err(err(format!(
                            "animation '{name}': unreadable channel outputs"
                        )));
                    }
                };
                let per_key = if interpolation == Interpolation::CubicSpline {
                    3
                } else {
                    1
                };
                if times.is_empty() || values.len() != times.len() * per_key {
                    return Err(err(format!(
                        "animation '{name}': {} keyframe times but {} values",
                        times.len(),
                        values.len()
                    )));
                }
                if times.iter().any(|t| !t.is_finite()) || times.windows(2).any(|w| w[1] <= w[0]) {
                    return Err(err(format!(
                        "animation '{name}': keyframe times are not finite and strictly increasing"
                    )));
                }
                if values.iter().flatten().any(|v| !v.is_finite()) {
                    return Err(err(format!(
                        "animation '{name}': non-finite keyframe values"
                    )));
                }
                duration = duration.max(*times.last().expect("non-empty"));
                channels.push(Channel {
                    node: ch.target().node().index(),
                    property,
                    interpolation,
                    times,
                    values,
                });
            }
            animations.push(Animation {
                name,
                duration,
                channels,
            });
        }
    }
    Ok(Character {
        mesh,
        rig,
        animations,
        skinned,
    })
}

/// The mesh nodes whose node or mesh name is `only` (case-insensitive); all with `None`.
fn choose_nodes<'a>(
    mesh_nodes: Vec<gltf::Node<'a>>,
    only: Option<&str>,
) -> std::result::Result<Vec<gltf::Node<'a>>, String> {
    let Some(want) = only else {
        return Ok(mesh_nodes);
    };
    let w = want.to_lowercase();
    let named = |n: &gltf::Node<'_>| {
        n.name().is_some_and(|x| x.to_lowercase() == w)
            || n.mesh()
                .and_then(|m| m.name().map(|x| x.to_lowercase() == w))
                .unwrap_or(false)
    };
    let names: Vec<String> = mesh_nodes
        .iter()
        .map(|n| n.name().unwrap_or("(unnamed)").to_string())
        .collect();
    let chosen: Vec<gltf::Node<'a>> = mesh_nodes.into_iter().filter(named).collect();
    if chosen.is_empty() {
        return Err(format!(
            "no mesh named '{want}'; the meshes are: {}",
            names.join(", ")
        ));
    }
    Ok(chosen)
}

/// The mesh nodes of the file's first skin (every mesh node without a skin).
fn skin_mesh_nodes<'a>(doc: &'a gltf::Document) -> Vec<gltf::Node<'a>> {
    let skin = doc.skins().next();
    doc.nodes()
        .filter(|n| n.mesh().is_some())
        .filter(|n| match &skin {
            Some(s) => n.skin().is_some_and(|ns| ns.index() == s.index()),
            None => true,
        })
        .collect()
}

/// The material of each named part (chosen as [`load_named`] chooses its nodes): the
/// base-colour factor and texture (decoded; embedded, external or a data URI). A part whose
/// primitives use two different materials, a texture read through a texture coordinate set
/// other than 0, an image that cannot be read or decoded, or one beyond
/// [`MAX_TEXTURE_SIDE`](super::material::MAX_TEXTURE_SIDE) is an error naming the file, the part and the image. A part with
/// no material gets glTF's default (white).
pub fn load_materials(path: &Path, names: &[&str]) -> Result<Vec<Material>> {
    let err = |m: String| Error::input(path, m);
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let gltf = gltf::Gltf::from_slice(&bytes).map_err(|e| err(format!("not valid glTF: {e}")))?;
    let doc = gltf.document;
    let base = path.parent().or(Some(Path::new(".")));
    let buffers = gltf::import_buffers(&doc, base, gltf.blob)
        .map_err(|e| err(format!("cannot load buffers: {e}")))?;
    // A texture transform moves the texture on the surface; reading the texture without it
    // would put it in the wrong place without a word.
    if doc.extensions_used().any(|e| e == "KHR_texture_transform") {
        return Err(err(
            "uses KHR_texture_transform, which vkshade does not apply to base-colour \
             textures (bake the transform into the UVs, or use the measured materials)"
                .into(),
        ));
    }
    let mut out = Vec::with_capacity(names.len());
    for name in names {
        let nodes = choose_nodes(skin_mesh_nodes(&doc), Some(name)).map_err(err)?;
        let mut chosen: Option<gltf::Material<'_>> = None;
        for n in &nodes {
            let mesh = n.mesh().expect("mesh nodes only");
            for prim in mesh.primitives() {
                let m = prim.material();
                match &chosen {
                    None => chosen = Some(m),
                    Some(c) if c.index() == m.index() => {}
                    Some(c) => {
                        let label = |m: &gltf::Material<'_>| match (m.index(), m.name()) {
                            (Some(i), Some(n)) => format!("{i} '{n}'"),
                            (Some(i), None) => format!("{i}"),
                            (None, _) => "the default".to_string(),
                        };
                        return Err(err(format!(
                            "part '{name}' uses materials {} and {}; the frame takes one \
                             material a part",
                            label(c),
                            label(&m)
                        )));
                    }
                }
            }
        }
        let Some(m) = chosen.filter(|m| m.index().is_some()) else {
            out.push(Material::default());
            continue;
        };
        let mname = m.name().map_or_else(
            || format!("material {}", m.index().unwrap_or(0)),
            str::to_string,
        );
        let pbr = m.pbr_metallic_roughness();
        let factor = pbr.base_color_factor();
        if factor
            .iter()
            .any(|f| !f.is_finite() || !(0.0..=1.0).contains(f))
        {
            return Err(err(format!(
                "part '{name}': material '{mname}' has baseColorFactor {factor:?} (each in [0, 1])"
            )));
        }
        let texture = match pbr.base_color_texture() {
            None => None,
            Some(info) => {
                if info.tex_coord() != 0 {
                    return Err(err(format!(
                        "part '{name}': material '{mname}' reads its base colour through \
                         TEXCOORD_{}; only TEXCOORD_0 is loaded",
                        info.tex_coord()
                    )));
                }
                Some(decode_texture(path, base, &buffers, info.texture(), name)?)
            }
        };
        out.push(Material {
            name: mname,
            factor,
            texture,
        });
    }
    Ok(out)
}

fn decode_texture(
    path: &Path,
    base: Option<&Path>,
    buffers: &[gltf::buffer::Data],
    tex: gltf::Texture<'_>,
    part: &str,
) -> Result<Texture> {
    use gltf::image::Format;
    use gltf::texture::WrappingMode;
    let image = tex.source();
    let source = match image.source() {
        gltf::image::Source::Uri { uri, .. } => {
            if uri.starts_with("data:") {
                format!("image {} (data URI)", image.index())
            } else {
                format!("image {} '{uri}'", image.index())
            }
        }
        gltf::image::Source::View { .. } => match image.name() {
            Some(n) => format!("image {} '{n}' (embedded)", image.index()),
            None => format!("image {} (embedded)", image.index()),
        },
    };
    let data = gltf::image::Data::from_source(image.source(), base, buffers).map_err(|e| {
        Error::input(
            path,
            format!("part '{part}': base-colour {source} cannot be read or decoded: {e}"),
        )
    })?;
    let (w, h) = (data.width, data.height);
    let px = w as usize * h as usize;
    let texels: Vec<u32> = match data.format {
        Format::R8 if data.pixels.len() == px => data
            .pixels
            .iter()
            .map(|&r| u32::from_le_bytes([r, r, r, 255]))
            .collect(),
        Format::R8G8 if data.pixels.len() == 2 * px => data
            .pixels
            .chunks_exact(2)
            .map(|c| u32::from_le_bytes([c[0], c[0], c[0], c[1]]))
            .collect(),
        Format::R8G8B8 if data.pixels.len() == 3 * px => data
            .pixels
            .chunks_exact(3)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], 255]))
            .collect(),
        Format::R8G8B8A8 if data.pixels.len() == 4 * px => data
            .pixels
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect(),
        f => {
            return Err(Error::input(
                path,
                format!(
                    "part '{part}': base-colour {source} decodes as {f:?}, {w} x {h}; \
                     8-bit images only"
                ),
            ));
        }
    };
    let wrap = |m: WrappingMode| match m {
        WrappingMode::Repeat => Wrap::Repeat,
        WrappingMode::ClampToEdge => Wrap::Clamp,
        WrappingMode::MirroredRepeat => Wrap::Mirror,
    };
    let s = tex.sampler();
    let t = Texture {
        source,
        width: w,
        height: h,
        texels,
        wrap: [wrap(s.wrap_s()), wrap(s.wrap_t())],
    };
    t.check(path)?;
    Ok(t)
}
