//! Pairwise distance constraints: rope segments (stiffness 1), rope bending (distance between
//! particles two apart, softer), and attachments of a rope end to another shape.

/// Structure of arrays over distance constraints between particles `a[k]` and `b[k]`.
#[derive(Clone, Debug, Default)]
pub struct DistanceConstraints {
    pub a: Vec<u32>,
    pub b: Vec<u32>,
    pub rest_length: Vec<f32>,
    /// Fraction of the violation corrected per projection, in (0, 1].
    pub stiffness: Vec<f32>,
}

impl DistanceConstraints {
    pub fn len(&self) -> usize {
        self.a.len()
    }

    pub fn is_empty(&self) -> bool {
        self.a.is_empty()
    }

    pub fn push(&mut self, a: u32, b: u32, rest_length: f32, stiffness: f32) {
        self.a.push(a);
        self.b.push(b);
        self.rest_length.push(rest_length);
        self.stiffness.push(stiffness);
    }
}
