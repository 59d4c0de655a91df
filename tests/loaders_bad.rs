//! Bad input to the mesh loaders (issue 21, points 1, 3, 5 and 6): a small glTF builder
//! makes a valid skinned, animated character (JSON + one binary buffer, as GLB or as .gltf
//! with an external .bin), and each test corrupts one field. Every corruption must come back
//! as an error naming the file and the real cause, from the file and from memory, never as
//! a panic (each load runs under `catch_unwind`). The OBJ, PLY, OFF and `.sph` cases follow.

#![cfg(feature = "gltf")]

mod common;

use serde_json::{Value, json};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use vkshade::scene::spheretree::{BuildConfig, Sphere, SphereTree};
use vkshade::scene::{self, Mesh, MeshData};

fn write(name: &str, bytes: &[u8]) -> PathBuf {
    common::temp_file("loaders-bad", name, bytes)
}

/// A glTF document and its one binary buffer.
#[derive(Clone)]
struct Gltf {
    json: Value,
    bin: Vec<u8>,
}

/// Byte offsets in the valid character's buffer.
const POS: usize = 0; // 4 x VEC3 f32
const UV: usize = 48; // 4 x VEC2 f32
const JOINTS: usize = 80; // 4 x VEC4 u8
const WEIGHTS: usize = 96; // 4 x VEC4 f32
const INDICES: usize = 160; // 12 x u16
const IBM: usize = 184; // 2 x MAT4 f32
const TIMES: usize = 312; // 2 x f32
const ROTATIONS: usize = 320; // 2 x VEC4 f32
const TRANSLATIONS: usize = 352; // 2 x VEC3 f32
const END: usize = 376;

fn f32s(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|f| f.to_le_bytes()).collect()
}

impl Gltf {
    /// A tetrahedron skinned to a two-joint chain, one animation rotating the child joint
    /// and moving the root.
    fn valid() -> Gltf {
        let mut bin = Vec::new();
        bin.extend(f32s(&[0., 0., 0., 1., 0., 0., 0., 1., 0., 0., 0., 1.]));
        bin.extend(f32s(&[0., 0., 1., 0., 0., 1., 0.5, 0.5]));
        bin.extend([0u8, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0]);
        bin.extend(f32s(&[
            1., 0., 0., 0., 1., 0., 0., 0., 1., 0., 0., 0., 0.5, 0.5, 0., 0.,
        ]));
        for i in [0u16, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3] {
            bin.extend(i.to_le_bytes());
        }
        let identity = glam::Mat4::IDENTITY.to_cols_array();
        let child = glam::Mat4::from_translation(glam::Vec3::new(0., -1., 0.)).to_cols_array();
        bin.extend(f32s(&identity));
        bin.extend(f32s(&child));
        bin.extend(f32s(&[0., 1.]));
        let q = glam::Quat::from_rotation_z(0.5).to_array();
        bin.extend(f32s(&[0., 0., 0., 1.]));
        bin.extend(f32s(&q));
        bin.extend(f32s(&[0., 0., 0., 0., 0.5, 0.]));
        assert_eq!(bin.len(), END);
        let view = |offset: usize, length: usize| json!({"buffer": 0, "byteOffset": offset, "byteLength": length});
        let json = json!({
            "asset": {"version": "2.0"},
            "scene": 0,
            "scenes": [{"nodes": [0, 1]}],
            "nodes": [
                {"name": "body", "mesh": 0, "skin": 0},
                {"name": "root", "children": [2]},
                {"name": "child", "translation": [0.0, 1.0, 0.0]}
            ],
            "skins": [{"joints": [1, 2], "inverseBindMatrices": 5}],
            "meshes": [{"name": "tet", "primitives": [{
                "attributes": {"POSITION": 0, "TEXCOORD_0": 1, "JOINTS_0": 2, "WEIGHTS_0": 3},
                "indices": 4
            }]}],
            "accessors": [
                {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
                 "min": [0, 0, 0], "max": [1, 1, 1]},
                {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
                {"bufferView": 2, "componentType": 5121, "count": 4, "type": "VEC4"},
                {"bufferView": 3, "componentType": 5126, "count": 4, "type": "VEC4"},
                {"bufferView": 4, "componentType": 5123, "count": 12, "type": "SCALAR"},
                {"bufferView": 5, "componentType": 5126, "count": 2, "type": "MAT4"},
                {"bufferView": 6, "componentType": 5126, "count": 2, "type": "SCALAR",
                 "min": [0], "max": [1]},
                {"bufferView": 7, "componentType": 5126, "count": 2, "type": "VEC4"},
                {"bufferView": 8, "componentType": 5126, "count": 2, "type": "VEC3"}
            ],
            "bufferViews": [
                view(POS, 48), view(UV, 32), view(JOINTS, 16), view(WEIGHTS, 64),
                view(INDICES, 24), view(IBM, 128), view(TIMES, 8), view(ROTATIONS, 32),
                view(TRANSLATIONS, 24)
            ],
            "buffers": [{"byteLength": END}],
            "animations": [{
                "name": "wave",
                "samplers": [
                    {"input": 6, "output": 7, "interpolation": "LINEAR"},
                    {"input": 6, "output": 8, "interpolation": "LINEAR"}
                ],
                "channels": [
                    {"sampler": 0, "target": {"node": 2, "path": "rotation"}},
                    {"sampler": 1, "target": {"node": 1, "path": "translation"}}
                ]
            }]
        });
        Gltf { json, bin }
    }

    /// Sets the JSON value at `pointer` (e.g. `/accessors/4/componentType`).
    fn set(mut self, pointer: &str, v: Value) -> Gltf {
        let (parent, key) = pointer.rsplit_once('/').unwrap();
        let p = self
            .json
            .pointer_mut(parent)
            .unwrap_or_else(|| panic!("no {parent}"));
        match p {
            Value::Object(m) => {
                m.insert(key.to_string(), v);
            }
            Value::Array(a) => a[key.parse::<usize>().unwrap()] = v,
            _ => panic!("{parent} is not a container"),
        }
        self
    }

    /// Overwrites buffer bytes at `offset` with little-endian floats.
    fn put(mut self, offset: usize, v: &[f32]) -> Gltf {
        let b = f32s(v);
        self.bin[offset..offset + b.len()].copy_from_slice(&b);
        self
    }

    /// Appends bytes to the buffer (keeping its declared length right) and a view over
    /// them; returns the view's index.
    fn append(&mut self, bytes: &[u8]) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        self.json["buffers"][0]["byteLength"] = json!(self.bin.len());
        let views = self.json["bufferViews"].as_array_mut().unwrap();
        views.push(json!({"buffer": 0, "byteOffset": offset, "byteLength": bytes.len()}));
        views.len() - 1
    }

    /// The binary glTF container.
    fn glb(&self) -> Vec<u8> {
        let mut js = serde_json::to_vec(&self.json).unwrap();
        while !js.len().is_multiple_of(4) {
            js.push(b' ');
        }
        let mut bin = self.bin.clone();
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        let total = 12 + 8 + js.len() + 8 + bin.len();
        let mut out = Vec::with_capacity(total);
        out.extend(b"glTF");
        out.extend(2u32.to_le_bytes());
        out.extend((total as u32).to_le_bytes());
        out.extend((js.len() as u32).to_le_bytes());
        out.extend(0x4E4F_534Au32.to_le_bytes());
        out.extend(js);
        out.extend((bin.len() as u32).to_le_bytes());
        out.extend(0x004E_4942u32.to_le_bytes());
        out.extend(bin);
        out
    }

    fn write(&self, name: &str) -> PathBuf {
        write(name, &self.glb())
    }
}

/// Loads `bytes` as `path` under `catch_unwind`; a panic fails the test naming `what`.
fn no_panic<T>(what: &str, f: impl FnOnce() -> vkshade::Result<T>) -> vkshade::Result<T> {
    catch_unwind(AssertUnwindSafe(f)).unwrap_or_else(|_| panic!("{what}: the loader panicked"))
}

/// Writes `g` as `name` (GLB), loads it from the file and from memory, and checks that both
/// are errors naming the file and containing every one of `want`. Returns the message.
fn refused(name: &str, g: &Gltf, want: &[&str]) -> String {
    let path = g.write(name);
    let e = common::error_naming(&path, no_panic(name, || scene::load(&path)));
    for w in want {
        assert!(e.contains(w), "{name}: '{w}' is not in the error: {e}");
    }
    let m = common::error_naming(&path, no_panic(name, || scene::load_bytes(&path, &g.glb())));
    assert_eq!(m, e, "{name}: loading from memory says something else");
    e
}

#[test]
fn the_valid_character_loads() {
    let g = Gltf::valid();
    let path = g.write("valid.glb");
    let c = scene::load(&path).unwrap();
    assert!(c.skinned);
    assert_eq!(
        (c.mesh.positions.len(), c.mesh.triangles.len()),
        (4, 4),
        "a tetrahedron"
    );
    assert_eq!(c.mesh.uvs.as_ref().unwrap()[3].to_array(), [0.5, 0.5]);
    let skin = c.mesh.skin.as_ref().unwrap();
    assert_eq!(
        (skin.joints[3], skin.weights[3]),
        ([0, 1, 0, 0], [0.5, 0.5, 0.0, 0.0])
    );
    assert_eq!(c.rig.joints, vec![1, 2]);
    assert_eq!(c.animations.len(), 1);
    assert_eq!(c.animations[0].channels.len(), 2);
    assert_eq!(c.animations[0].duration, 1.0);
    // The same from memory, and as .gltf with an external .bin beside it.
    let m = scene::load_bytes(&path, &g.glb()).unwrap();
    assert_eq!(m.mesh.positions, c.mesh.positions);
    let bin = write("valid-ext.bin", &g.bin);
    let mut ext = g.clone();
    ext.json["buffers"][0]["uri"] = json!(bin.file_name().unwrap().to_str().unwrap());
    let gl = write("valid-ext.gltf", &serde_json::to_vec(&ext.json).unwrap());
    let e = scene::load(&gl).unwrap();
    assert_eq!(e.mesh.triangles, c.mesh.triangles);
}

/// Issue 21 point 1: component types the specification forbids for a semantic reached
/// `unreachable!()` in the gltf crate; each is now an error naming mesh, primitive,
/// attribute, accessor and the forbidden form.
#[test]
fn forbidden_component_types_are_errors_not_panics() {
    for (name, pointer, ct, want) in [
        (
            "idx-float.glb",
            "/accessors/4/componentType",
            5126,
            ["indices", "accessor 4", "SCALAR of FLOAT"],
        ),
        (
            "joints-float.glb",
            "/accessors/2/componentType",
            5126,
            ["JOINTS_0", "accessor 2", "VEC4 of FLOAT"],
        ),
        (
            "weights-short.glb",
            "/accessors/3/componentType",
            5122,
            ["WEIGHTS_0", "accessor 3", "VEC4 of SHORT"],
        ),
        (
            "uv-uint.glb",
            "/accessors/1/componentType",
            5125,
            ["TEXCOORD_0", "accessor 1", "VEC2 of UNSIGNED_INT"],
        ),
        (
            "rot-uint.glb",
            "/accessors/7/componentType",
            5125,
            ["channel 0", "accessor 7", "VEC4 of UNSIGNED_INT"],
        ),
        (
            "ibm-short.glb",
            "/accessors/5/componentType",
            5122,
            ["inverseBindMatrices", "accessor 5", "SHORT"],
        ),
        (
            "times-byte.glb",
            "/accessors/6/componentType",
            5121,
            ["keyframe times", "accessor 6", "UNSIGNED_BYTE"],
        ),
    ] {
        let e = refused(name, &Gltf::valid().set(pointer, json!(ct)), &want);
        assert!(
            e.contains("mesh 0 'tet' primitive 0")
                || e.contains("animation 0 'wave'")
                || e.contains("skin 0"),
            "{e}"
        );
    }
    // The normalized flag: required for integer texture coordinates, forbidden on floats.
    refused(
        "uv-u16-raw.glb",
        &Gltf::valid()
            .set("/accessors/1/componentType", json!(5123))
            .set("/accessors/1/count", json!(4)),
        &[
            "TEXCOORD_0",
            "VEC2 of UNSIGNED_SHORT",
            "normalized UNSIGNED_SHORT",
        ],
    );
    refused(
        "pos-normalized.glb",
        &Gltf::valid().set("/accessors/0/normalized", json!(true)),
        &["POSITION", "VEC3 of normalized FLOAT"],
    );
}

/// Found by `mutated_glb_never_panics`: the gltf crate's validation indexed POSITION's
/// accessor without a bounds check.
#[test]
fn a_position_accessor_index_out_of_range_is_an_error() {
    refused(
        "pos-index.glb",
        &Gltf::valid().set("/meshes/0/primitives/0/attributes/POSITION", json!(90)),
        &["mesh 0 primitive 0: POSITION is accessor 90, but the file has 9 accessors"],
    );
}

#[test]
fn a_channel_targeting_a_missing_node_is_an_error() {
    refused(
        "target-node.glb",
        &Gltf::valid().set("/animations/0/channels/0/target/node", json!(99)),
        &["animation 0 'wave' channel 0", "targets node 99", "3 nodes"],
    );
}

/// Point 6 and the position messages of point 5: counts, offsets, strides and views that
/// point past the data are refused before anything is read or allocated.
#[test]
fn accessors_views_and_buffers_past_the_data_are_refused() {
    refused(
        "idx-1e9.glb",
        &Gltf::valid().set("/accessors/4/count", json!(1_000_000_000u64)),
        &[
            "indices",
            "accessor 4",
            "1000000000 elements",
            "points past its buffer view",
        ],
    );
    refused(
        "pos-offset.glb",
        &Gltf::valid().set("/accessors/0/byteOffset", json!(40)),
        &["POSITION", "accessor 0", "points past its buffer view"],
    );
    refused(
        "pos-stride.glb",
        &Gltf::valid().set("/bufferViews/0/byteStride", json!(252)),
        &["POSITION", "stride 252", "points past its buffer view"],
    );
    refused(
        "pos-stride-small.glb",
        &Gltf::valid().set("/bufferViews/0/byteStride", json!(8)),
        &["POSITION", "byteStride 8, less than the element size 12"],
    );
    refused(
        "pos-view.glb",
        &Gltf::valid().set("/bufferViews/0/byteOffset", json!(360)),
        &[
            "POSITION",
            "buffer view 0",
            "points past the end of buffer 0",
        ],
    );
    refused(
        "pos-misaligned.glb",
        &Gltf::valid().set("/bufferViews/0/byteOffset", json!(2)),
        &["POSITION", "not aligned"],
    );
    refused(
        "buffer-short.glb",
        &Gltf::valid().set("/buffers/0/byteLength", json!(100)),
        &["buffer 0 declares byteLength 100", "376 bytes"],
    );
    refused(
        "buffer-long.glb",
        &Gltf::valid().set("/buffers/0/byteLength", json!(1000)),
        &["buffer 0 declares byteLength 1000", "only 376 bytes"],
    );
    refused(
        "pos-vec2.glb",
        &Gltf::valid().set("/accessors/0/type", json!("VEC2")),
        &[
            "POSITION",
            "accessor 0",
            "is VEC2 of FLOAT",
            "only VEC3 of FLOAT",
        ],
    );
    refused(
        "uv-count.glb",
        &Gltf::valid().set("/accessors/1/count", json!(3)),
        &["TEXCOORD_0 has 3 elements but POSITION has 4"],
    );
    let mut g = Gltf::valid();
    g.bin[INDICES] = 9;
    refused("idx-range.glb", &g, &["index 9 out of range (4 vertices)"]);
}

/// Sparse substitutions on POSITION: indices out of range, not increasing, of a float type,
/// or more than the accessor's count.
#[test]
fn junk_sparse_indices_are_refused() {
    let sparse = |indices: &[u32], count: usize| {
        let mut g = Gltf::valid();
        let iv = g.append(
            &indices
                .iter()
                .flat_map(|i| i.to_le_bytes())
                .collect::<Vec<u8>>(),
        );
        let vv = g.append(&f32s(&vec![0.25; 3 * indices.len()]));
        g.set(
            "/accessors/0/sparse",
            json!({"count": count,
                   "indices": {"bufferView": iv, "componentType": 5125},
                   "values": {"bufferView": vv}}),
        )
    };
    // A good substitution first: vertex 1 moves to (0.25, 0.25, 0.25).
    let good = sparse(&[1], 1);
    let c = scene::load(&good.write("sparse-good.glb")).unwrap();
    assert_eq!(c.mesh.positions[1].to_array(), [0.25; 3]);
    refused(
        "sparse-range.glb",
        &sparse(&[1, 7], 2),
        &["POSITION", "sparse index 1 is 7", "4 elements"],
    );
    refused(
        "sparse-order.glb",
        &sparse(&[3, 1], 2),
        &["POSITION", "not strictly increasing (1 follows 3)"],
    );
    refused(
        "sparse-count.glb",
        &sparse(&[0, 1, 2, 3, 0], 5),
        &["sparse count 5 is not in 1..=4"],
    );
    refused(
        "sparse-past.glb",
        &sparse(&[1], 2),
        &["sparse indices", "points past its buffer view"],
    );
}

/// Point 6: a zero or non-finite scale must not collapse a skinned mesh to a point (it gave
/// occlusion 1 everywhere); a scale of 1e20 must not blow it up (an infinite sphere tree).
#[test]
fn collapsing_or_exploding_transforms_are_refused() {
    refused(
        "scale-zero.glb",
        &Gltf::valid().set("/nodes/1/scale", json!([0.0, 0.0, 0.0])),
        &[
            "collapses the skinned mesh to a point",
            "node 1 'root' has scale [0.0, 0.0, 0.0]",
        ],
    );
    refused(
        "scale-huge.glb",
        &Gltf::valid().set("/nodes/1/scale", json!([1e20, 1e20, 1e20])),
        &["node 1 'root'", "beyond the coordinate bound"],
    );
    // 1e39 overflows f32: the JSON reader refuses it or it arrives as infinity.
    let e = refused(
        "scale-inf.glb",
        &Gltf::valid().set("/nodes/1/scale", json!([1e39, 1.0, 1.0])),
        &[],
    );
    assert!(
        e.contains("node 1 'root' has a non-finite transform") || e.contains("not valid glTF"),
        "{e}"
    );
    refused(
        "anim-scale-zero.glb",
        &Gltf::valid()
            .set("/animations/0/channels/1/target/path", json!("scale"))
            .set("/animations/0/channels/1/target/node", json!(1))
            .put(TRANSLATIONS, &[0.0; 6]),
        &["animation 'wave' at 0 s scales every weighted joint to zero"],
    );
    refused(
        "anim-far.glb",
        &Gltf::valid().put(TRANSLATIONS, &[0., 0., 0., 0., 1e20, 0.]),
        &["channel 1", "beyond the coordinate bound"],
    );
    refused(
        "rot-zero.glb",
        &Gltf::valid().put(ROTATIONS, &[0.0; 4]),
        &["channel 0", "not a unit quaternion"],
    );
    refused(
        "node-rot-zero.glb",
        &Gltf::valid().set("/nodes/2/rotation", json!([0.0, 0.0, 0.0, 0.0])),
        &["node 2 'child'", "not a unit quaternion"],
    );
}

/// Point 5: the messages name the real cause.
#[test]
fn messages_name_the_real_cause() {
    refused(
        "self-child.glb",
        &Gltf::valid().set("/nodes/2/children", json!([2])),
        &["node 2 'child' lists itself as its own child", "cycle"],
    );
    refused(
        "two-parents.glb",
        &Gltf::valid().set("/nodes/0/children", json!([2])),
        &["node 2 'child' is a child of both node 0 and node 1"],
    );
    refused(
        "cubic.glb",
        &Gltf::valid().set(
            "/animations/0/samplers/0/interpolation",
            json!("CUBICSPLINE"),
        ),
        &[
            "channel 0",
            "CUBICSPLINE needs 3 output values per keyframe",
            "2 keyframe times need 6 values, the output has 2",
        ],
    );
    refused(
        "keys-count.glb",
        &Gltf::valid().set("/accessors/8/count", json!(1)),
        &["channel 1", "2 keyframe times but 1 output values"],
    );
    // A missing external .bin is named with the path it was looked for at.
    let mut g = Gltf::valid();
    g.json["buffers"][0]["uri"] = json!("no-such-buffer.bin");
    let path = write("missing-bin.gltf", &serde_json::to_vec(&g.json).unwrap());
    let e = common::error_naming(&path, no_panic("missing-bin", || scene::load(&path)));
    let resolved = path.parent().unwrap().join("no-such-buffer.bin");
    assert!(
        e.contains(&resolved.display().to_string()) && e.contains("buffer 0"),
        "{e}"
    );
    // From memory there is no directory to look in: said so, not a panic.
    let e = common::error_naming(
        &path,
        no_panic("missing-bin mem", || {
            scene::load_bytes(&path, &serde_json::to_vec(&g.json).unwrap())
        }),
    );
    assert!(e.contains("cannot be read when loading from memory"), "{e}");
    // Coordinates of 1e20 are refused by the loader, naming the file and the vertex.
    refused(
        "far.glb",
        &Gltf::valid().put(POS + 12, &[1e20, 0.0, 0.0]),
        &["vertex 1", "beyond the coordinate bound"],
    );
}

/// Point 3: weights must be finite, non-negative and bounded; joints inside the skin.
#[test]
fn bad_skin_weights_are_refused() {
    refused(
        "weight-3e38.glb",
        &Gltf::valid().put(WEIGHTS, &[3e38, 0.0, 0.0, 0.0]),
        &["vertex 0", "skin weight 3e38", "above the bound"],
    );
    refused(
        "weight-neg.glb",
        &Gltf::valid().put(WEIGHTS, &[-1.0, 2.0, 0.0, 0.0]),
        &["vertex 0", "negative skin weight"],
    );
    let mut g = Gltf::valid();
    g.bin[JOINTS] = 7;
    refused("joint-7.glb", &g, &["vertex 0", "joint 7", "2 joints"]);
}

thread_local! {
    /// Where panics on this thread are recorded instead of printed (None: printed).
    static PANICS: std::cell::RefCell<Option<Vec<String>>> = const { std::cell::RefCell::new(None) };
}

/// Mutations of the valid GLB (every byte set to three values, every truncation): none may
/// panic. Every panic is collected (with its location) and the test fails listing them. The
/// lead's cargo-fuzz targets go further; this keeps a cheap guard in `cargo test`.
#[test]
fn mutated_glb_never_panics() {
    let previous = std::sync::Arc::new(std::panic::take_hook());
    let chained = previous.clone();
    std::panic::set_hook(Box::new(move |info| {
        let recorded = PANICS.with(|p| match p.borrow_mut().as_mut() {
            Some(list) => {
                list.push(format!("{info}"));
                true
            }
            None => false,
        });
        if !recorded {
            chained(info);
        }
    }));
    PANICS.with(|p| *p.borrow_mut() = Some(Vec::new()));
    let glb = Gltf::valid().glb();
    let name = Path::new("mutant.glb");
    let (mut loaded, mut runs) = (0, 0);
    let mut failures: Vec<String> = Vec::new();
    let mut run = |what: String, bytes: &[u8]| -> Option<bool> {
        match catch_unwind(AssertUnwindSafe(|| scene::load_bytes(name, bytes))) {
            Ok(r) => Some(r.is_ok()),
            Err(_) => {
                let msg = PANICS.with(|p| p.borrow_mut().as_mut().and_then(|l| l.pop()));
                failures.push(format!("{what}: {}", msg.unwrap_or_default()));
                None
            }
        }
    };
    for i in 0..glb.len() {
        for v in [0u8, 0xff, b'9'] {
            let mut m = glb.clone();
            if m[i] == v {
                continue;
            }
            m[i] = v;
            runs += 1;
            loaded += (run(format!("byte {i} = {v:#x}"), &m) == Some(true)) as usize;
        }
    }
    for n in 0..glb.len() {
        runs += 1;
        let ok = run(format!("cut at {n}"), &glb[..n]);
        assert!(
            ok != Some(true),
            "a GLB cut to {n} of {} bytes loaded",
            glb.len()
        );
    }
    PANICS.with(|p| *p.borrow_mut() = None);
    eprintln!(
        "{runs} mutated GLBs, {loaded} still loaded (harmless edits), {} panics",
        failures.len()
    );
    assert!(failures.is_empty(), "panics:\n{}", failures.join("\n"));
    assert!(loaded < runs / 2, "most mutations must be refused");
}

fn load_err(name: &str, bytes: &[u8]) -> String {
    let path = write(name, bytes);
    let e = common::error_naming(&path, no_panic(name, || scene::load(&path)));
    let m = common::error_naming(&path, no_panic(name, || scene::load_bytes(&path, bytes)));
    assert_eq!(e, m, "{name}: memory and file disagree");
    e
}

/// Point 5 for the static formats: non-finite and out-of-bound values are refused naming the
/// file and the line (text) or element (PLY); huge header counts allocate nothing.
#[test]
fn static_formats_refuse_non_finite_and_huge_values() {
    let e = load_err("inf.obj", b"v 0 0 0\nv 1e39 0 0\nv 0 1 0\nf 1 2 3\n");
    assert!(e.contains("line 2") && e.contains("not a finite"), "{e}");
    let e = load_err("far.obj", b"v 0 0 0\nv 1e20 0 0\nv 0 1 0\nf 1 2 3\n");
    assert!(
        e.contains("line 2") && e.contains("coordinate bound"),
        "{e}"
    );
    let e = load_err("nan.off", b"OFF\n3 1 0\n0 0 0\n1 NaN 0\n0 1 0\n3 0 1 2\n");
    assert!(e.contains("line 4") && e.contains("not a finite"), "{e}");
    let e = load_err("huge.off", b"OFF\n1000000000000 1 0\n0 0 0\n");
    assert!(e.contains("ends before 1000000000000 vertices"), "{e}");
    let e = load_err("overflow.off", b"OFF\n99999999999999999999999 1 0\n");
    assert!(e.contains("bad counts"), "{e}");
    let ply = |body: &str| {
        format!(
            "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
             property float z\nelement face 1\nproperty list uchar int vertex_indices\n\
             end_header\n{body}"
        )
    };
    let e = load_err(
        "far.ply",
        ply("0 0 0\n1e20 0 0\n0 1 0\n3 0 1 2\n").as_bytes(),
    );
    assert!(
        e.contains("vertex 1") && e.contains("coordinate bound"),
        "{e}"
    );
    let e = load_err(
        "inf.ply",
        ply("0 0 0\n1e39 0 0\n0 1 0\n3 0 1 2\n").as_bytes(),
    );
    assert!(
        e.contains("vertex 1") && e.contains("property x") && e.contains("not a finite"),
        "{e}"
    );
    let e = load_err(
        "idx.ply",
        ply("0 0 0\n1 0 0\n0 1 0\n3 0 1 5000000000\n").as_bytes(),
    );
    assert!(e.contains("face 0") && e.contains("too large"), "{e}");
    // Binary: a NaN y.
    let mut bin = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n".to_vec();
    bin.extend(f32s(&[0., 0., 0., 1., f32::NAN, 0., 0., 1., 0.]));
    bin.push(3);
    for i in [0i32, 1, 2] {
        bin.extend(i.to_le_bytes());
    }
    let e = load_err("nan.ply", &bin);
    assert!(e.contains("vertex 1") && e.contains("property y"), "{e}");
}

fn tri_mesh(scale: f32) -> Mesh {
    // A closed octahedron.
    let p = [
        [1., 0., 0.],
        [-1., 0., 0.],
        [0., 1., 0.],
        [0., -1., 0.],
        [0., 0., 1.],
        [0., 0., -1.],
    ];
    let d = MeshData {
        name: "octahedron".into(),
        positions: p.iter().map(|v: &[f32; 3]| v.map(|c| c * scale)).collect(),
        triangles: vec![
            [0, 2, 4],
            [2, 1, 4],
            [1, 3, 4],
            [3, 0, 4],
            [2, 0, 5],
            [1, 2, 5],
            [3, 1, 5],
            [0, 3, 5],
        ],
        ..Default::default()
    };
    Mesh::from_data(d, Path::new("octahedron")).unwrap()
}

/// Point 3: at the coordinate bound the sphere-tree builder still gives finite spheres (its
/// volume arithmetic used to overflow f32 near 1e13); beyond it, meshes are refused at load;
/// trees with non-finite or out-of-bound spheres are neither written nor read.
#[test]
fn sphere_trees_stay_finite_and_bad_ones_are_refused() {
    let cfg = BuildConfig {
        depth: 2,
        branch: 4,
        samples: 2000,
        ..Default::default()
    };
    for scale in [1.0, vkshade::scene::mesh::MAX_COORDINATE] {
        let (t, _) = SphereTree::build(&tri_mesh(scale), &cfg).unwrap();
        let root = t.spheres[0];
        assert!(
            root.center.is_finite() && root.radius.is_finite() && root.radius > 0.5 * scale,
            "scale {scale}: root {root:?}"
        );
    }
    let e = std::panic::catch_unwind(|| {
        let d = MeshData {
            positions: vec![[0., 0., 0.], [1e20, 0., 0.], [0., 1., 0.]],
            triangles: vec![[0, 1, 2]],
            ..Default::default()
        };
        Mesh::from_data(d, Path::new("scaled.obj")).map(|_| ())
    })
    .unwrap()
    .unwrap_err()
    .to_string();
    assert!(e.contains("scaled.obj") && e.contains("vertex 1"), "{e}");

    // A mesh past the bound that bypassed the loaders (its fields are public) gets no tree
    // with infinite or out-of-bound spheres from the builder: an error naming the mesh.
    let mut far = tri_mesh(1.0);
    far.positions.iter_mut().for_each(|p| *p *= 1e20);
    let e = SphereTree::build(&far, &cfg).unwrap_err().to_string();
    assert!(
        e.contains("octahedron") && e.contains("sphere tree built for this mesh is unusable"),
        "{e}"
    );

    let (mut t, _) = SphereTree::build(&tri_mesh(1.0), &cfg).unwrap();
    t.spheres[0] = Sphere {
        center: glam::Vec3::ZERO,
        radius: f32::INFINITY,
    };
    let out = common::temp_dir("loaders-bad").join("inf.sph");
    let e = t.write_sph(&out).unwrap_err().to_string();
    assert!(
        e.contains("inf.sph") && e.contains("node 0") && e.contains("not written"),
        "{e}"
    );
    assert!(!out.exists(), "a refused tree left a file");
    for (name, text, want) in [
        (
            "rad.sph",
            "2 2\n0 0 0 3e38 1\n0 0 0 1 1\n0 0 0 1 1\n",
            "node 0",
        ),
        (
            "inf.sph",
            "2 2\n0 0 0 1 1\n0 0 1e39 1 1\n0 0 0 1 1\n",
            "not a finite",
        ),
        (
            "nan.sph",
            "2 2\n0 0 0 1 1\n0 0 0 1 1\n0 0 0 1 nan\n",
            "not a finite",
        ),
    ] {
        let path = write(name, text.as_bytes());
        let e = common::error_naming(&path, no_panic(name, || SphereTree::read_sph(&path)));
        assert!(e.contains(want), "{name}: {e}");
        let m = SphereTree::parse_sph(&path, text.as_bytes())
            .unwrap_err()
            .to_string();
        assert_eq!(m, e);
    }
}

/// A normal of 3e38 (finite, but its length overflows) becomes a unit normal, not zero.
#[test]
fn huge_normals_normalise() {
    let d = MeshData {
        positions: vec![[0., 0., 0.], [1., 0., 0.], [0., 1., 0.]],
        normals: Some(vec![[0., 0., 3e38], [3e38, 3e38, 0.], [0., 0., 1.]]),
        triangles: vec![[0, 1, 2]],
        ..Default::default()
    };
    let m = Mesh::from_data(d, Path::new("n")).unwrap();
    for n in &m.normals {
        assert!((n.length() - 1.0).abs() < 1e-5, "{n:?}");
    }
}

/// The strict checks accept the characters shipped under data/ (every mesh node, and from
/// memory as from the file), with their animations.
#[test]
fn the_shipped_characters_still_load() {
    for name in ["testwuson.glb", "bcn_epileptic.glb", "human.glb"] {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("data")
            .join(name);
        let c = scene::load(&path).unwrap_or_else(|e| panic!("{e}; run tools/setup.sh"));
        let bytes = std::fs::read(&path).unwrap();
        let m = scene::load_bytes(&path, &bytes).unwrap();
        assert_eq!(m.mesh.positions, c.mesh.positions, "{name}");
        eprintln!(
            "{name}: {} vertices, {} triangles, skinned {}, {} animations",
            c.mesh.positions.len(),
            c.mesh.triangles.len(),
            c.skinned,
            c.animations.len()
        );
    }
}

/// The static formats and `.sph` under the same mutations as the GLB (every byte set to
/// three values, every truncation): errors or meshes, never a panic.
#[test]
fn mutated_static_files_never_panic() {
    let obj = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvt 0 0\nvn 0 0 1\nf 1/1/1 2/1/1 3/1/1\nf 1 4 2\nf -1 -2 -3\n".to_vec();
    let off = b"OFF\n4 2 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n4 0 1 2 3\n".to_vec();
    let ascii_ply = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0 0 0 1\n1 0 0 0 0 1\n0 1 0 0 0 1\n3 0 1 2\n".to_vec();
    let mut bin_ply = b"ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty double x\nproperty double y\nproperty double z\nelement face 1\nproperty list uchar uint vertex_indices\nend_header\n".to_vec();
    for v in [0f64, 0., 0., 1., 0., 0., 0., 1., 0.] {
        bin_ply.extend(v.to_be_bytes());
    }
    bin_ply.push(3);
    for i in [0u32, 1, 2] {
        bin_ply.extend(i.to_be_bytes());
    }
    let sph = b"2 2\n0 0 0 1 1\n0.5 0 0 0.5 0.5\n-0.5 0 0 0.5 0.5\n".to_vec();
    let mut runs = 0;
    let mut panics = Vec::new();
    for (name, file) in [
        ("m.obj", &obj),
        ("m.off", &off),
        ("a.ply", &ascii_ply),
        ("b.ply", &bin_ply),
        ("t.sph", &sph),
    ] {
        let path = Path::new(name);
        let mut check = |what: String, bytes: &[u8]| {
            runs += 1;
            let r = catch_unwind(AssertUnwindSafe(|| {
                if name.ends_with(".sph") {
                    SphereTree::parse_sph(path, bytes).map(|_| ())
                } else {
                    scene::load_bytes(path, bytes).map(|_| ())
                }
            }));
            if r.is_err() {
                panics.push(format!("{name} {what}"));
            }
        };
        check("as is".into(), file);
        for i in 0..file.len() {
            for v in [0u8, 0xff, b'9', b'-', b'\n'] {
                let mut m = file.clone();
                m[i] = v;
                check(format!("byte {i} = {v:#x}"), &m);
            }
            check(format!("cut at {i}"), &file[..i]);
        }
    }
    eprintln!("{runs} mutated static files, {} panics", panics.len());
    assert!(panics.is_empty(), "panics: {panics:?}");
}

/// An embedded base-colour image whose view points past the buffer: the gltf crate sliced
/// it unchecked (a panic); now an error naming the part and the image.
#[test]
fn an_image_view_past_the_buffer_is_an_error() {
    let mut g = Gltf::valid();
    g.json["bufferViews"]
        .as_array_mut()
        .unwrap()
        .push(json!({"buffer": 0, "byteOffset": 360, "byteLength": 100}));
    g.json["images"] = json!([{"bufferView": 9, "mimeType": "image/png"}]);
    g.json["textures"] = json!([{"source": 0}]);
    g.json["materials"] = json!([{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]);
    g.json["meshes"][0]["primitives"][0]["material"] = json!(0);
    let path = g.write("image-view.glb");
    let e = common::error_naming(
        &path,
        no_panic("image-view", || {
            scene::gltf_load::load_materials(&path, &["tet"])
        }),
    );
    assert!(
        e.contains("part 'tet'")
            && e.contains("image 0")
            && e.contains("points past the end of buffer 0"),
        "{e}"
    );
}

/// A PNG header (CRC-checked, so a decoder trusts it) claiming more texels than the file
/// could hold.
fn png_bomb(w: u32, h: u32) -> Vec<u8> {
    let mut b = b"\x89PNG\r\n\x1a\n".to_vec();
    for (kind, data) in [
        (
            &b"IHDR"[..],
            [
                &w.to_be_bytes()[..],
                &h.to_be_bytes()[..],
                &[16, 6, 0, 0, 0][..],
            ]
            .concat(),
        ),
        (&b"IDAT"[..], b"\x78\x9c\x03\x00\x00\x00\x00\x01".to_vec()),
    ] {
        let chunk = [kind, &data[..]].concat();
        b.extend((data.len() as u32).to_be_bytes());
        b.extend(&chunk);
        b.extend(common::crc32(&chunk).to_be_bytes());
    }
    b
}

/// An embedded base-colour PNG whose header claims 8192 x 8192 16-bit RGBA texels (512 MiB
/// decoded) in 60 bytes: the crate's decoder allocated all of it before failing (the
/// `btf_image` fuzz target found the same in the BTF loader). Refused from the header,
/// naming the part, the image and the bound.
#[test]
fn an_embedded_image_claiming_more_than_it_holds_is_refused_before_decoding() {
    let mut g = Gltf::valid();
    let view = g.append(&png_bomb(8192, 8192));
    g.json["images"] = json!([{"bufferView": view, "mimeType": "image/png"}]);
    g.json["textures"] = json!([{"source": 0}]);
    g.json["materials"] = json!([{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]);
    g.json["meshes"][0]["primitives"][0]["material"] = json!(0);
    let path = g.write("image-bomb.glb");
    let e = common::error_naming(
        &path,
        no_panic("image-bomb", || {
            scene::gltf_load::load_materials(&path, &["tet"])
        }),
    );
    assert!(
        e.contains("part 'tet'") && e.contains("image 0") && e.contains("8192 x 8192"),
        "{e}"
    );
}
