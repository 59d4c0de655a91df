//! Node hierarchies, skins and keyframe animation (glTF semantics), evaluated on the CPU:
//! a character has tens of joints, so the GPU only receives the final skinning matrices.

use glam::{Mat4, Quat, Vec3};

/// Translation, rotation, scale.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Trs {
    pub t: Vec3,
    pub r: Quat,
    pub s: Vec3,
}

impl Default for Trs {
    fn default() -> Self {
        Trs {
            t: Vec3::ZERO,
            r: Quat::IDENTITY,
            s: Vec3::ONE,
        }
    }
}

impl Trs {
    pub fn matrix(&self) -> Mat4 {
        Mat4::from_scale_rotation_translation(self.s, self.r, self.t)
    }
}

#[derive(Clone, Debug)]
pub struct Node {
    pub name: String,
    pub parent: Option<usize>,
    pub rest: Trs,
}

/// A node hierarchy with the joints of one skin.
#[derive(Clone, Debug)]
pub struct Rig {
    pub nodes: Vec<Node>,
    /// Node index of each joint, in the skin's joint order.
    pub joints: Vec<usize>,
    /// One per joint.
    pub inverse_bind: Vec<Mat4>,
    /// Nodes ordered so that every parent precedes its children.
    order: Vec<usize>,
}

/// Which property a channel animates.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Property {
    Translation,
    Rotation,
    Scale,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interpolation {
    Step,
    Linear,
    /// Values are stored as (in-tangent, value, out-tangent) triples.
    CubicSpline,
}

/// Keyframes of one property of one node. Rotations are stored as (x, y, z, w).
#[derive(Clone, Debug)]
pub struct Channel {
    pub node: usize,
    pub property: Property,
    pub interpolation: Interpolation,
    /// Strictly increasing, seconds.
    pub times: Vec<f32>,
    pub values: Vec<[f32; 4]>,
}

#[derive(Clone, Debug)]
pub struct Animation {
    pub name: String,
    /// Last keyframe time, seconds.
    pub duration: f32,
    pub channels: Vec<Channel>,
}

impl Rig {
    /// Builds a rig; fails on a cycle or out-of-range indices (the caller names the file).
    pub fn new(
        nodes: Vec<Node>,
        joints: Vec<usize>,
        inverse_bind: Vec<Mat4>,
    ) -> std::result::Result<Rig, String> {
        if joints.len() != inverse_bind.len() {
            return Err(format!(
                "{} joints but {} inverse bind matrices",
                joints.len(),
                inverse_bind.len()
            ));
        }
        if let Some(j) = joints.iter().find(|&&j| j >= nodes.len()) {
            return Err(format!("joint refers to node {j} of {}", nodes.len()));
        }
        if let Some((i, m)) = inverse_bind
            .iter()
            .enumerate()
            .find(|(_, m)| !m.is_finite())
        {
            return Err(format!("inverse bind matrix {i} is not finite: {m:?}"));
        }
        let mut order = Vec::with_capacity(nodes.len());
        let mut state = vec![0u8; nodes.len()]; // 0 new, 1 visiting, 2 done
        for start in 0..nodes.len() {
            let mut chain = Vec::new();
            let mut n = Some(start);
            while let Some(i) = n {
                if i >= nodes.len() {
                    return Err(format!("node parent index {i} out of range"));
                }
                match state[i] {
                    2 => break,
                    1 => return Err(format!("node hierarchy has a cycle through node {i}")),
                    _ => {}
                }
                state[i] = 1;
                chain.push(i);
                n = nodes[i].parent;
            }
            for &i in chain.iter().rev() {
                state[i] = 2;
                order.push(i);
            }
        }
        Ok(Rig {
            nodes,
            joints,
            inverse_bind,
            order,
        })
    }

    /// A rig of one identity joint (static meshes).
    pub fn identity() -> Rig {
        Rig::new(
            vec![Node {
                name: "root".into(),
                parent: None,
                rest: Trs::default(),
            }],
            vec![0],
            vec![Mat4::IDENTITY],
        )
        .expect("trivially valid")
    }

    /// Local transforms of every node at `time` of `anim` (rest pose without an animation).
    pub fn pose(&self, anim: Option<&Animation>, time: f32) -> Vec<Trs> {
        let mut local: Vec<Trs> = self.nodes.iter().map(|n| n.rest).collect();
        if let Some(anim) = anim {
            for ch in &anim.channels {
                if ch.node >= local.len() || ch.times.is_empty() {
                    continue;
                }
                let v = ch.sample(time);
                let trs = &mut local[ch.node];
                match ch.property {
                    Property::Translation => trs.t = Vec3::new(v[0], v[1], v[2]),
                    Property::Scale => trs.s = Vec3::new(v[0], v[1], v[2]),
                    Property::Rotation => {
                        let q = Quat::from_xyzw(v[0], v[1], v[2], v[3]);
                        if q.length() > 1e-6 {
                            trs.r = q.normalize()
                        }
                    }
                }
            }
        }
        local
    }

    /// World transform of every node for the given local transforms.
    pub fn globals(&self, local: &[Trs]) -> Vec<Mat4> {
        let mut global = vec![Mat4::IDENTITY; self.nodes.len()];
        for &i in &self.order {
            let m = local[i].matrix();
            global[i] = match self.nodes[i].parent {
                Some(p) => global[p] * m,
                None => m,
            };
        }
        global
    }

    /// Skinning matrices (joint world transform x inverse bind) at `time` of `anim`.
    pub fn skinning_matrices(&self, anim: Option<&Animation>, time: f32) -> Vec<Mat4> {
        let global = self.globals(&self.pose(anim, time));
        self.joints
            .iter()
            .zip(&self.inverse_bind)
            .map(|(&j, ibm)| global[j] * *ibm)
            .collect()
    }
}

impl Channel {
    /// The value at `time`, clamped to the first and last keyframes.
    pub fn sample(&self, time: f32) -> [f32; 4] {
        let n = self.times.len();
        let key = |i: usize| match self.interpolation {
            Interpolation::CubicSpline => self.values[3 * i + 1],
            _ => self.values[i],
        };
        if n == 1 || time <= self.times[0] {
            return key(0);
        }
        if time >= self.times[n - 1] {
            return key(n - 1);
        }
        // First keyframe after `time`.
        let hi = self.times.partition_point(|&t| t <= time).clamp(1, n - 1);
        let lo = hi - 1;
        let dt = self.times[hi] - self.times[lo];
        let u = if dt > 0.0 {
            (time - self.times[lo]) / dt
        } else {
            0.0
        };
        match self.interpolation {
            Interpolation::Step => key(lo),
            Interpolation::Linear => {
                let (a, b) = (key(lo), key(hi));
                if self.property == Property::Rotation {
                    let qa = Quat::from_array(a);
                    let qb = Quat::from_array(b);
                    qa.slerp(qb, u).to_array()
                } else {
                    std::array::from_fn(|k| a[k] + (b[k] - a[k]) * u)
                }
            }
            Interpolation::CubicSpline => {
                let (p0, m0) = (self.values[3 * lo + 1], self.values[3 * lo + 2]);
                let (p1, m1) = (self.values[3 * hi + 1], self.values[3 * hi]);
                let (u2, u3) = (u * u, u * u * u);
                let h00 = 2.0 * u3 - 3.0 * u2 + 1.0;
                let h10 = u3 - 2.0 * u2 + u;
                let h01 = -2.0 * u3 + 3.0 * u2;
                let h11 = u3 - u2;
                let mut v: [f32; 4] = std::array::from_fn(|k| {
                    h00 * p0[k] + h10 * dt * m0[k] + h01 * p1[k] + h11 * dt * m1[k]
                });
                if self.property == Property::Rotation {
                    // Tangents can cancel the values (a zero quaternion): keep the nearer
                    // keyframe rather than a NaN rotation.
                    let near = if u < 0.5 { p0 } else { p1 };
                    v = glam::Vec4::from_array(v)
                        .try_normalize()
                        .map_or(Quat::from_array(near).normalize(), Quat::from_vec4)
                        .to_array();
                }
                v
            }
        }
    }
}

/// Linear-blend skinning of one point or direction (`w` = 1 or 0) with four influences.
pub fn blend_matrix(matrices: &[Mat4], joints: [u16; 4], weights: [f32; 4]) -> Mat4 {
    let mut m = Mat4::ZERO;
    for k in 0..4 {
        if weights[k] != 0.0 {
            m += matrices[joints[k] as usize] * weights[k];
        }
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chain() -> Rig {
        let nodes = vec![
            Node {
                name: "a".into(),
                parent: None,
                rest: Trs {
                    t: Vec3::new(1.0, 0.0, 0.0),
                    ..Default::default()
                },
            },
            Node {
                name: "b".into(),
                parent: Some(0),
                rest: Trs {
                    t: Vec3::new(0.0, 2.0, 0.0),
                    ..Default::default()
                },
            },
        ];
        Rig::new(nodes, vec![1], vec![Mat4::IDENTITY]).unwrap()
    }

    #[test]
    fn globals_compose_parents_first() {
        let r = chain();
        let g = r.globals(&r.pose(None, 0.0));
        assert!((g[1].w_axis.truncate() - Vec3::new(1.0, 2.0, 0.0)).length() < 1e-6);
    }

    #[test]
    fn cycles_are_rejected() {
        let mut nodes = chain().nodes;
        nodes[0].parent = Some(1);
        assert!(Rig::new(nodes, vec![0], vec![Mat4::IDENTITY]).is_err());
    }

    #[test]
    fn linear_and_step_sampling() {
        let ch = Channel {
            node: 0,
            property: Property::Translation,
            interpolation: Interpolation::Linear,
            times: vec![0.0, 1.0, 3.0],
            values: vec![[0.0; 4], [2.0, 0.0, 0.0, 0.0], [4.0, 0.0, 0.0, 0.0]],
        };
        assert_eq!(ch.sample(0.5)[0], 1.0);
        assert_eq!(ch.sample(2.0)[0], 3.0);
        assert_eq!(ch.sample(-1.0)[0], 0.0);
        assert_eq!(ch.sample(9.0)[0], 4.0);
        let step = Channel {
            interpolation: Interpolation::Step,
            ..ch
        };
        assert_eq!(step.sample(0.99)[0], 0.0);
        assert_eq!(step.sample(1.5)[0], 2.0);
    }

    #[test]
    fn cubic_rotation_through_zero_stays_finite() {
        // Values q and -q with zero tangents: the Hermite blend passes through zero at u = 0.5.
        let q = Quat::from_rotation_y(0.3).to_array();
        let ch = Channel {
            node: 0,
            property: Property::Rotation,
            interpolation: Interpolation::CubicSpline,
            times: vec![0.0, 1.0],
            values: vec![[0.0; 4], q, [0.0; 4], [0.0; 4], q.map(|c| -c), [0.0; 4]],
        };
        for t in [0.25, 0.5, 0.75] {
            let v = ch.sample(t);
            let l = Quat::from_array(v).length();
            assert!(
                v.iter().all(|c| c.is_finite()) && (l - 1.0).abs() < 1e-5,
                "{t}: {v:?}"
            );
        }
    }

    #[test]
    fn rotation_uses_slerp() {
        let q0 = Quat::IDENTITY;
        let q1 = Quat::from_rotation_z(std::f32::consts::FRAC_PI_2);
        let ch = Channel {
            node: 0,
            property: Property::Rotation,
            interpolation: Interpolation::Linear,
            times: vec![0.0, 1.0],
            values: vec![q0.to_array(), q1.to_array()],
        };
        let q = Quat::from_array(ch.sample(0.5));
        let expect = Quat::from_rotation_z(std::f32::consts::FRAC_PI_4);
        assert!(q.angle_between(expect) < 1e-5);
    }
}
