// stencil.wgsl ↔ crates/cpu/src/spring_forces/stencil.rs: the fused step's springs for models whose
// bodies are all lattices (cuboids, mesh bodies), found on the body's lattice by lattice.wgsl;
// imported by the fused step (explicit.wgsl) in place of fused_gather.wgsl (and so gather.wgsl)
// where it is composed with `stencil` (`Stage::FusedStencil`). No spring record and no adjacency is
// read.
//
// gather(i) has gather.wgsl's result bit for bit. The CSR run of particle i at point p is, in
// ascending spring order, the springs ending at p (first end p − d, which ascends as the linear
// offset of d descends), then those starting at p in topology::OFFSETS order; the sum here
// takes exactly these, −f then +f, in that order, each computed by fused_gather.wgsl's call
// spring_force(spring, x_a, x_b, v_a, v_b) in the spring's own (a, b) orientation. A spring
// that does not exist is skipped, not added as a zero. Two offsets of equal linear offset
// never both end at one point (its partner would be one point at two places), so their
// relative order in `backward` does not matter.

#import common
#import lattice

// Σ of particle i's spring forces at the state (x, v), own_x and own_v being its own: the
// CSR gather's sum (above).
fn gather(i: u32) -> vec3<f32> {
    let s = stencil_of(i);
    let body = &lattice_bodies[s.body];
    let n = (*body).n_offsets;
    var sum = vec3<f32>(0.0);
    for (var r = 0u; r < n; r++) {
        let offset = (*body).offsets[(*body).backward[r]];
        let q = step_point(s.point, offset, -1);
        if in_grid(s, s.p - offset.d) && kept(s, offset, q) {
            let a = particle_at(s, q);
            sum -= spring_force(lattice_spring(offset, a, i), x[a].xyz, own_x, v[a].xyz, own_v);
        }
    }
    for (var r = 0u; r < n; r++) {
        let offset = (*body).offsets[r];
        if in_grid(s, s.p + offset.d) && kept(s, offset, s.point) {
            let o = particle_at(s, step_point(s.point, offset, 1));
            sum += spring_force(lattice_spring(offset, i, o), own_x, x[o].xyz, own_v, v[o].xyz);
        }
    }
    return sum;
}
