// updates.wgsl: the explicit integrators' update equations on y = (x, v), y' = (v, a), which
// explicit.wgsl's kernels apply on both paths (a read from its buffer on the per-spring path,
// computed in the kernel on the fused one): the same f32 operations in the same order on both,
// which is what keeps the two paths bit-identical.

struct Y {
    x: vec4<f32>,
    v: vec4<f32>,
}

// y + s (v_s, a): an Euler step, a Runge–Kutta stage, or the midpoint update, from y along the
// rate (v_s, a).
fn advance(y: Y, vs: vec4<f32>, a: vec4<f32>, s: f32) -> Y {
    return Y(y.x + s * vs, y.v + s * a);
}

// Symplectic Euler: v' = v + h a, x' = x + h v'.
fn symplectic(y: Y, a: vec4<f32>, h: f32) -> Y {
    let vn = y.v + h * a;
    return Y(y.x + h * vn, vn);
}

// RK4's running sum after a middle stage: sum + 2 (v_s, a).
fn rk4_accumulate(sum: Y, vs: vec4<f32>, a: vec4<f32>) -> Y {
    return Y(sum.x + 2.0 * vs, sum.v + 2.0 * a);
}

// RK4's last stage: y + h/6 (sum + (v_s, a)).
fn rk4_finish(y: Y, sum: Y, vs: vec4<f32>, a: vec4<f32>, h: f32) -> Y {
    return advance(y, sum.x + vs, sum.v + a, h / 6.0);
}
