//! glTF 2.0 (.gltf / .glb) characters: the skinned mesh, its skeleton and animations.
//!
//! The mesh is every triangle primitive of the nodes that use the file's first skin (so a
//! character split into several meshes comes back whole); without a skin, every mesh node,
//! transformed to world space. Texture images are decoded only by [`load_materials`].
//!
//! Nothing is read through the gltf crate's accessor readers: [`super::gltf_access`] checks
//! every accessor against the specification and the bytes before reading it. Errors name the
//! file and the mesh/primitive, skin or animation/channel, the attribute, the accessor and
//! the cause. Vertices beyond [`MAX_COORDINATE`] are refused, and so is a skeleton whose
//! rest pose or keyframes collapse the skinned mesh to a point or move it past the bound.

use super::Character;
use super::gltf_access as access;
use super::material::{Material, Texture, Wrap};
use super::mesh::{MAX_COORDINATE, Mesh, MeshData};
use super::rig::{Animation, Channel, Interpolation, Node, Property, Rig, Trs, blend_matrix};
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
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let base = path.parent().unwrap_or(Path::new("."));
    from_bytes(path, &bytes, Some(base), only)
}

/// A glTF/GLB character from memory (as [`load`]; `name` is only used in error messages).
/// Buffers must be embedded (GLB BIN chunk or data URIs): an external `.bin` is an error,
/// since there is no directory to resolve it in. The entry point for fuzzing.
pub fn load_bytes(name: &Path, bytes: &[u8]) -> Result<Character> {
    from_bytes(name, bytes, None, None)
}

/// The GLB header's total length, checked before the gltf crate subtracts the header size
/// from it (an underflow, a panic with overflow checks on, for a length below 12).
fn check_glb_header(bytes: &[u8]) -> std::result::Result<(), String> {
    if bytes.starts_with(b"glTF") && bytes.len() >= 12 {
        let length = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]);
        if length < 12 {
            return Err(format!(
                "not valid glTF: the GLB header declares a total length of {length} bytes, \
                 less than the 12-byte header itself"
            ));
        }
    }
    Ok(())
}

/// Parses and validates a glTF/GLB document. The gltf crate's own validation indexes the
/// accessor of every POSITION attribute without a bounds check, so that index is checked
/// first, on the unvalidated document.
fn parse(bytes: &[u8]) -> std::result::Result<gltf::Gltf, String> {
    use gltf::json::validation::Checked;
    check_glb_header(bytes)?;
    let g = gltf::Gltf::from_slice_without_validation(bytes)
        .map_err(|e| format!("not valid glTF: {e}"))?;
    let root = g.document.as_json();
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            let pos = prim
                .attributes
                .get(&Checked::Valid(gltf::json::mesh::Semantic::Positions));
            if let Some(i) = pos.filter(|i| i.value() >= root.accessors.len()) {
                return Err(format!(
                    "mesh {m} primitive {p}: POSITION is accessor {}, but the file has {} \
                     accessors",
                    i.value(),
                    root.accessors.len()
                ));
            }
        }
    }
    let document = gltf::Document::from_json(g.document.into_json())
        .map_err(|e| format!("not valid glTF: {e}"))?;
    Ok(gltf::Gltf {
        document,
        blob: g.blob,
    })
}

fn node_label(doc: &gltf::Document, i: usize) -> String {
    match doc.nodes().nth(i).and_then(|n| n.name()) {
        Some(n) => format!("node {i} '{n}'"),
        None => format!("node {i}"),
    }
}

fn from_bytes(
    path: &Path,
    bytes: &[u8],
    base: Option<&Path>,
    only: Option<&str>,
) -> Result<Character> {
    use access::{read, to_f32, to_u32};
    use gltf::json::mesh::Semantic;
    use gltf::json::validation::Checked;
    let err = |m: String| Error::input(path, m);
    let gltf = parse(bytes).map_err(err)?;
    let doc = gltf.document;
    let buffers = access::load_buffers(&doc, gltf.blob, base).map_err(err)?;
    let root = doc.as_json();

    // Node hierarchy.
    let mut nodes: Vec<Node> = Vec::with_capacity(root.nodes.len());
    for n in doc.nodes() {
        let (t, r, s) = n.transform().decomposed();
        let label = node_label(&doc, n.index());
        if !t.iter().chain(&r).chain(&s).all(|v| v.is_finite()) {
            return Err(err(format!(
                "{label} has a non-finite transform (translation {t:?}, rotation {r:?}, \
                 scale {s:?})"
            )));
        }
        if t.iter().chain(&s).any(|v| v.abs() > MAX_COORDINATE) {
            return Err(err(format!(
                "{label} has translation {t:?} / scale {s:?} beyond the coordinate bound \
                 {MAX_COORDINATE:e}"
            )));
        }
        let q = Quat::from_array(r);
        if q.length() < 1e-6 {
            return Err(err(format!(
                "{label} has rotation {r:?}, which is not a unit quaternion"
            )));
        }
        nodes.push(Node {
            name: n.name().unwrap_or("").to_string(),
            parent: None,
            rest: Trs {
                t: Vec3::from_array(t),
                r: q.normalize(),
                s: Vec3::from_array(s),
            },
        });
    }
    for n in doc.nodes() {
        for c in n.children() {
            if c.index() == n.index() {
                return Err(err(format!(
                    "{} lists itself as its own child: the node hierarchy has a cycle",
                    node_label(&doc, n.index())
                )));
            }
            if let Some(p) = nodes[c.index()].parent {
                return Err(err(format!(
                    "{} is a child of both node {p} and node {} (a node has one parent)",
                    node_label(&doc, c.index()),
                    n.index()
                )));
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
        let Some(mesh) = node.mesh() else {
            continue;
        };
        let to_world = if skin.is_some() {
            Mat4::IDENTITY
        } else {
            world[node.index()]
        };
        let det = Mat3::from_mat4(to_world).determinant();
        if !to_world.is_finite() || !det.is_finite() || det.abs() < 1e-30 {
            return Err(err(format!(
                "{} has a degenerate world transform (determinant {det}): a zero or \
                 overflowing scale on it or an ancestor collapses its mesh",
                node_label(&doc, node.index())
            )));
        }
        let normal_matrix = Mat3::from_mat4(to_world).inverse().transpose();
        let jmesh = &root.meshes[mesh.index()];
        let mname = mesh.name().unwrap_or("");
        for (pi, prim) in jmesh.primitives.iter().enumerate() {
            let what = format!("mesh {} '{mname}' primitive {pi}", mesh.index());
            match prim.mode {
                Checked::Valid(gltf::json::mesh::Mode::Triangles) => {}
                Checked::Valid(m) => {
                    return Err(err(format!(
                        "{what}: primitive mode {m:?} is not supported (triangles only)"
                    )));
                }
                Checked::Invalid => {
                    return Err(err(format!("{what}: unknown primitive mode")));
                }
            }
            let attr = |s: Semantic| prim.attributes.get(&Checked::Valid(s)).map(|i| i.value());
            let at = |sem: &str| {
                let what = what.clone();
                let sem = sem.to_string();
                move |m: String| Error::input(path, format!("{what}: {sem} {m}"))
            };
            let pos_ai = attr(Semantic::Positions)
                .ok_or_else(|| err(format!("{what} has no POSITION attribute")))?;
            let pos: Vec<[f32; 3]> =
                read(root, &buffers, pos_ai, access::POSITION, to_f32).map_err(at("POSITION"))?;
            let count = pos.len();
            let same_count = |sem: &str, n: usize| {
                if n == count {
                    Ok(())
                } else {
                    Err(err(format!(
                        "{what}: {sem} has {n} elements but POSITION has {count} (the \
                         attributes of a primitive have one count)"
                    )))
                }
            };
            let base_index = data.positions.len() as u32;
            data.positions.extend(
                pos.iter()
                    .map(|p| to_world.transform_point3(Vec3::from_array(*p)).to_array()),
            );
            match attr(Semantic::Normals) {
                Some(ai) => {
                    let n: Vec<[f32; 3]> =
                        read(root, &buffers, ai, access::NORMAL, to_f32).map_err(at("NORMAL"))?;
                    same_count("NORMAL", n.len())?;
                    normals.extend(
                        n.iter()
                            .map(|v| (normal_matrix * Vec3::from_array(*v)).to_array()),
                    )
                }
                None => all_normals = false,
            }
            match attr(Semantic::TexCoords(0)) {
                Some(ai) => {
                    let t: Vec<[f32; 2]> = read(root, &buffers, ai, access::TEXCOORD, to_f32)
                        .map_err(at("TEXCOORD_0"))?;
                    same_count("TEXCOORD_0", t.len())?;
                    uvs.extend(t)
                }
                None => all_uvs = false,
            }
            if skin.is_some() {
                let mut inf: Vec<Vec<(u32, f32)>> = vec![Vec::new(); count];
                let mut set = 0;
                loop {
                    let (ja, wa) = match (attr(Semantic::Joints(set)), attr(Semantic::Weights(set)))
                    {
                        (Some(j), Some(w)) => (j, w),
                        (None, None) => break,
                        _ => {
                            return Err(err(format!(
                                "{what}: JOINTS_{set} and WEIGHTS_{set} come in pairs; one is \
                                 missing"
                            )));
                        }
                    };
                    let j: Vec<[u32; 4]> = read(root, &buffers, ja, access::JOINTS, to_u32)
                        .map_err(at(&format!("JOINTS_{set}")))?;
                    let w: Vec<[f32; 4]> = read(root, &buffers, wa, access::WEIGHTS, to_f32)
                        .map_err(at(&format!("WEIGHTS_{set}")))?;
                    same_count(&format!("JOINTS_{set}"), j.len())?;
                    same_count(&format!("WEIGHTS_{set}"), w.len())?;
                    for v in 0..count {
                        for k in 0..4 {
                            inf[v].push((j[v][k], w[v][k]));
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
            let indices: Vec<u32> = match prim.indices {
                Some(ai) => read::<u32, 1>(root, &buffers, ai.value(), access::INDICES, to_u32)
                    .map_err(at("indices"))?
                    .into_iter()
                    .map(|[i]| i)
                    .collect(),
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
            let ibm: Vec<Mat4> = match root.skins[s.index()].inverse_bind_matrices {
                Some(ai) => {
                    read::<f32, 16>(root, &buffers, ai.value(), access::INVERSE_BIND, to_f32)
                        .map_err(|m| err(format!("skin {}: inverseBindMatrices {m}", s.index())))?
                        .iter()
                        .map(Mat4::from_cols_array)
                        .collect()
                }
                None => vec![Mat4::IDENTITY; joints.len()],
            };
            data.joint_count = joints.len();
            data.influences = Some(influences);
            Rig::new(nodes, joints, ibm).map_err(|m| err(format!("skin {}: {m}", s.index())))?
        }
        None => Rig::identity(),
    };
    let skinned = skin.is_some();
    let mesh = Mesh::from_data(data, path)?;

    let mut animations = Vec::new();
    if skinned {
        for ((ai, janim), anim) in root.animations.iter().enumerate().zip(doc.animations()) {
            let name = anim
                .name()
                .map(str::to_string)
                .unwrap_or_else(|| format!("animation{ai}"));
            let mut channels = Vec::new();
            let mut duration = 0f32;
            for (ci, ch) in janim.channels.iter().enumerate() {
                let what = format!("animation {ai} '{name}' channel {ci}");
                let node = ch.target.node.value();
                if node >= rig.nodes.len() {
                    return Err(err(format!(
                        "{what} targets node {node}, but the file has {} nodes",
                        rig.nodes.len()
                    )));
                }
                use gltf::json::animation::{Interpolation as I, Property as P};
                let property = match ch.target.path {
                    Checked::Valid(P::Translation) => Property::Translation,
                    Checked::Valid(P::Rotation) => Property::Rotation,
                    Checked::Valid(P::Scale) => Property::Scale,
                    Checked::Valid(P::MorphTargetWeights) => continue,
                    Checked::Invalid => {
                        return Err(err(format!("{what}: unknown target path")));
                    }
                };
                let Some(sampler) = janim.samplers.get(ch.sampler.value()) else {
                    return Err(err(format!(
                        "{what} uses sampler {}, which does not exist",
                        ch.sampler.value()
                    )));
                };
                let interpolation = match sampler.interpolation {
                    Checked::Valid(I::Step) => Interpolation::Step,
                    Checked::Valid(I::Linear) => Interpolation::Linear,
                    Checked::Valid(I::CubicSpline) => Interpolation::CubicSpline,
                    Checked::Invalid => {
                        return Err(err(format!("{what}: unknown interpolation")));
                    }
                };
                let times: Vec<f32> =
                    read::<f32, 1>(root, &buffers, sampler.input.value(), access::TIMES, to_f32)
                        .map_err(|m| err(format!("{what}: input (keyframe times) {m}")))?
                        .into_iter()
                        .map(|[t]| t)
                        .collect();
                let out = sampler.output.value();
                let bad_out = |m: String| err(format!("{what}: output (keyframe values) {m}"));
                let values: Vec<[f32; 4]> = match property {
                    Property::Translation | Property::Scale => {
                        read::<f32, 3>(root, &buffers, out, access::VEC3_KEYS, to_f32)
                            .map_err(bad_out)?
                            .into_iter()
                            .map(|[x, y, z]| [x, y, z, 0.0])
                            .collect()
                    }
                    Property::Rotation => {
                        read::<f32, 4>(root, &buffers, out, access::ROTATION_KEYS, to_f32)
                            .map_err(bad_out)?
                    }
                };
                let per_key = if interpolation == Interpolation::CubicSpline {
                    3
                } else {
                    1
                };
                if per_key == 3 && values.len() != 3 * times.len() {
                    return Err(err(format!(
                        "{what}: CUBICSPLINE needs 3 output values per keyframe (in-tangent, \
                         value, out-tangent): {} keyframe times need {} values, the output \
                         has {}",
                        times.len(),
                        3 * times.len(),
                        values.len()
                    )));
                }
                if values.len() != times.len() * per_key {
                    return Err(err(format!(
                        "{what}: {} keyframe times but {} output values (one per keyframe)",
                        times.len(),
                        values.len()
                    )));
                }
                if times.iter().any(|t| !t.is_finite()) || times.windows(2).any(|w| w[1] <= w[0]) {
                    return Err(err(format!(
                        "{what}: keyframe times are not finite and strictly increasing"
                    )));
                }
                if let Some(v) = values
                    .iter()
                    .find(|v| v.iter().any(|c| !c.is_finite() || c.abs() > MAX_COORDINATE))
                {
                    return Err(err(format!(
                        "{what}: keyframe value {v:?} is not finite or beyond the coordinate \
                         bound {MAX_COORDINATE:e}"
                    )));
                }
                if property == Property::Rotation {
                    let keys = values.iter().skip(per_key / 2).step_by(per_key);
                    if let Some(q) = keys.clone().find(|q| Quat::from_array(**q).length() < 1e-6) {
                        return Err(err(format!(
                            "{what}: rotation keyframe {q:?} is not a unit quaternion"
                        )));
                    }
                }
                duration = duration.max(times.last().copied().unwrap_or(0.0));
                channels.push(Channel {
                    node,
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
        check_poses(&mesh, &rig, &animations).map_err(err)?;
    }
    Ok(Character {
        mesh,
        rig,
        animations,
        skinned,
    })
}

/// Most keyframe times per animation at which [`check_poses`] evaluates the skeleton.
const POSE_CHECKS_PER_ANIMATION: usize = 64;

/// Refuses a skeleton that collapses or blows up the skinned mesh: the rest pose must keep
/// every vertex finite and within [`MAX_COORDINATE`] and must not shrink the mesh to a point
/// (a zero node scale would otherwise give occlusion 1 everywhere without a word); at up to
/// [`POSE_CHECKS_PER_ANIMATION`] keyframe times of each animation, the skinning matrices of
/// the weighted joints must be finite, keep the bind-space bounds within the coordinate
/// bound, and not all scale to zero.
fn check_poses(
    mesh: &Mesh,
    rig: &Rig,
    animations: &[Animation],
) -> std::result::Result<(), String> {
    let Some(skin) = &mesh.skin else {
        return Ok(());
    };
    let (lo, hi) = mesh.bounds();
    let bind_extent = (hi - lo).max_element();
    let reach = lo.abs().max(hi.abs()).max_element();
    let mut used = vec![false; rig.joints.len()];
    for (j, w) in skin.joints.iter().zip(&skin.weights) {
        for k in 0..4 {
            if w[k] > 0.0 && (j[k] as usize) < used.len() {
                used[j[k] as usize] = true;
            }
        }
    }
    let zero_scales = || {
        let z: Vec<String> = rig
            .nodes
            .iter()
            .enumerate()
            .filter(|(_, n)| n.rest.s.abs().min_element() == 0.0)
            .map(|(i, n)| format!("node {i} '{}' has scale {:?}", n.name, n.rest.s.to_array()))
            .collect();
        if z.is_empty() {
            String::new()
        } else {
            format!("; {}", z.join(", "))
        }
    };
    let rest = rig.skinning_matrices(None, 0.0);
    let (mut plo, mut phi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for (i, ((p, j), w)) in mesh
        .positions
        .iter()
        .zip(&skin.joints)
        .zip(&skin.weights)
        .enumerate()
    {
        let q = blend_matrix(&rest, *j, *w).transform_point3(*p);
        if !q.is_finite() || q.abs().max_element() > MAX_COORDINATE {
            return Err(format!(
                "the rest pose puts vertex {i} at {:?}, beyond the coordinate bound \
                 {MAX_COORDINATE:e} (a node's translation or scale is too large)",
                q.to_array()
            ));
        }
        plo = plo.min(q);
        phi = phi.max(q);
    }
    let extent = (phi - plo).max_element();
    if extent <= 1e-6 * bind_extent {
        return Err(format!(
            "the rest pose collapses the skinned mesh to a point (extent {extent:e} against \
             {bind_extent:e} in bind space){}",
            zero_scales()
        ));
    }
    for a in animations {
        let mut times: Vec<f32> = a.channels.iter().flat_map(|c| c.times.clone()).collect();
        times.sort_by(f32::total_cmp);
        times.dedup();
        let step = times.len().div_ceil(POSE_CHECKS_PER_ANIMATION).max(1);
        for &t in times.iter().step_by(step) {
            let m = rig.skinning_matrices(Some(a), t);
            let mut largest_linear = 0f32;
            for (j, mj) in m.iter().enumerate().filter(|(j, _)| used[*j]) {
                let lin = Mat3::from_mat4(*mj);
                let l = lin.abs().to_cols_array().into_iter().fold(0f32, f32::max);
                let bound = 3.0 * l * reach + mj.w_axis.truncate().abs().max_element();
                if !mj.is_finite() || !bound.is_finite() || bound > MAX_COORDINATE {
                    return Err(format!(
                        "animation '{}' at {t} s moves joint {j} so that the mesh may reach \
                         {bound:e}, beyond the coordinate bound {MAX_COORDINATE:e}",
                        a.name
                    ));
                }
                largest_linear = largest_linear.max(l);
            }
            if largest_linear < 1e-6 {
                return Err(format!(
                    "animation '{}' at {t} s scales every weighted joint to zero, collapsing \
                     the skinned mesh to a point",
                    a.name
                ));
            }
        }
    }
    Ok(())
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
    let gltf = parse(&bytes).map_err(err)?;
    let doc = gltf.document;
    let base = path.parent().or(Some(Path::new(".")));
    let buffers = access::load_buffers(&doc, gltf.blob, base).map_err(err)?;
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
                let root = doc.as_json();
                Some(decode_texture(
                    path,
                    base,
                    root,
                    &buffers,
                    info.texture(),
                    name,
                )?)
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
    root: &gltf::json::Root,
    buffers: &access::Buffers,
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
    let bad = |m: String| Error::input(path, format!("part '{part}': base-colour {source}: {m}"));
    // The encoded bytes, to check the header's size before the crate decodes (it allocates
    // what the header claims); the crate also slices an embedded image's view unchecked.
    let encoded: Vec<u8> = match image.source() {
        gltf::image::Source::View { view, .. } => access::view_bytes(root, buffers, view.index())
            .map_err(bad)?
            .0
            .to_vec(),
        gltf::image::Source::Uri { uri, .. } if uri.starts_with("data:") => {
            gltf::buffer::Data::from_source_and_blob(
                gltf::buffer::Source::Uri(uri),
                None,
                &mut None,
            )
            .map_err(|e| bad(format!("its data URI cannot be decoded: {e}")))?
            .0
        }
        gltf::image::Source::Uri { uri, .. } => match base {
            Some(dir) => {
                let file = dir.join(access::percent_decode(uri));
                std::fs::read(&file)
                    .map_err(|e| bad(format!("its file {} cannot be read: {e}", file.display())))?
            }
            None => Vec::new(), // the crate reports the missing base below
        },
    };
    if !encoded.is_empty() {
        crate::io::image_bounds::check_header(&encoded).map_err(bad)?;
    }
    let data = gltf::image::Data::from_source(image.source(), base, &buffers.0).map_err(|e| {
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
