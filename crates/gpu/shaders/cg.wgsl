// cg.wgsl ↔ crates/cpu/src/integrators/implicit_euler/cg.rs: filtered, block-Jacobi
// preconditioned conjugate gradients (Baraff and Witkin's modified PCG) for A Δv = rhs, where
// each particle's constraint filters the prescribed directions out:
//
//   constraints[i] = (n, kind): kind 0 free (S p = p), 1 normal (S p = p − (p·n) n), 2 fixed
//   (S p = 0); z holds the prescribed part of Δv. P⁻¹ is the inverse diagonal block of
//   system.wgsl (`diag`), applied as S P⁻¹ S. The filter and the partial sums are
//   cg_common.wgsl's, shared with the iteration's product.
//
// A solve, as the host encodes it (product.wgsl provides A p):
//
//   the warm start's projection (below): Δv = Σ x_j u-basis_j, the combination of the last
//                 solve's Δv and the two steps' before it closest to the solution;
//   cg_start:     Δv = S Δv + z;
//                 partials of wᵀP⁻¹w for the weight's impulse w = S h m g and of the
//                 resolution's Σ ρ_i² tr(S P⁻¹ S) (in cᵀq's half, unused until the first
//                 iteration)
//   apply_particles(Δv) → q = A Δv
//   cg_residual:  r = S(rhs − q), c = S P⁻¹ r;  partials of (Sb)ᵀP⁻¹(Sb) and rᵀc
//   cg_begin:     δ₀, δ, δ_w; scale = max(δ₀, δ, δ_w);
//                 target = max(tol²·scale, RESOLVED·Σ ρ_i² tr(S P⁻¹ S));
//                 done = !(δ > target)
//   then per iteration, while not done:
//   apply_particles_curvature(c) → q = S A c;  partials of cᵀq
//   cg_advance:   α = δ / cᵀq  (stop if cᵀq is not positive and finite: round-off);
//                 Δv += α c, r −= α q;  partials of rᵀP⁻¹r
//   cg_direction: δ' = Σ; stop on non-finite or round-off growth (δ' > 1e6·smallest: δ = smallest);
//                 β = δ'/δ, δ = δ'; iterations + 1; done = !(δ > target) or the cap;
//                 c = S(P⁻¹ r + β c)
//
// — the CPU's loop, operation for operation, in f32, but for the target's floor at what the
// f32 state resolves of b (docs/physics.md, "Filtered preconditioned conjugate gradients").
// Dot products are deterministic two-pass sums: each workgroup writes its tree sum
// (reduce.wgsl) to `partials`, and the partials are added in order (`sum_in_order`), on the
// device: no read-back per iteration, no float atomics. The one-workgroup kernel cg_begin
// adds them once; every workgroup of cg_advance adds cᵀq's, and
// every workgroup of cg_direction adds rᵀP⁻¹r's, themselves (the same code on the same input:
// the same α and β everywhere, bit for bit what one-workgroup kernels computed before), which
// saves two dispatches per iteration, and the product filters q and writes cᵀq's partials as it
// forms A c (on the particle grid, as a kernel of its own did before it, so the same bits),
// which saves a third. So cᵀq's partials have a half of `partials` of their own (`CURVATURE`):
// cg_advance reads them while it writes rᵀP⁻¹r's.
//
// The scalars live in `scalars` (twin: `softbody_gpu::layout::CgScalars`); where a kernel's
// first workgroup rewrites a scalar that the others read, they read a copy made by an earlier
// dispatch instead (`previous_delta`, kept by cg_advance, which only reads δ). The iteration's
// product and cg_advance are dispatched indirectly from `dispatch`, whose argument
// slots cg_begin and cg_direction rewrite: the full grids while the solve runs, zero workgroups
// once it is done, so that the host can encode a batch of iterations per submission and the
// surplus costs little. These two bind the arguments, so they are dispatched directly (a
// buffer cannot be both in one dispatch) and return at once once the solve has stopped: for
// cg_direction that is a full grid of workgroups that each read `done` and leave. cg_advance,
// dispatched indirectly, cannot write the arguments: when it finds cᵀq unusable it only sets
// `done`, and cg_direction, next, empties the slots. The "finished" slots are the
// reverse (zero while running, full once done): the active-set update after a solve
// (implicit_euler.wgsl) is encoded behind each batch and runs once, at the end.

#import common
#import reduce
#import cg_common

struct CgScalars {
    // rᵀP⁻¹r of the current residual.
    delta: f32,
    // max((Sb)ᵀP⁻¹(Sb), r₀ᵀP⁻¹r₀, wᵀP⁻¹w): what the residual is relative to.
    scale: f32,
    // tol²·scale.
    target_delta: f32,
    // The smallest δ so far (round-off guard).
    smallest: f32,
    alpha: f32,
    beta: f32,
    iterations: u32,
    // 1 once the solve has stopped.
    done: u32,
    // Set by the host: the relative tolerance, the iteration cap, the number of per-workgroup
    // partial sums (workgroups of the particle grid) and the grids (workgroups along x and y).
    tolerance: f32,
    max_iterations: u32,
    n_partials: u32,
    // δ at the iteration's start, for cg_direction's β (see above).
    previous_delta: f32,
    particle_grid: vec2<u32>,
    spring_grid: vec2<u32>,
    // The warm start's coefficients x_j (cg_project_solve).
    warm_start: array<f32, 3>,
    _pad: u32,
}

// Indirect dispatch arguments (x, y, z) per slot; see DISPATCH_* and `set_dispatch`.
const DISPATCH_PARTICLES: u32 = 0u;
const DISPATCH_SPRINGS: u32 = 3u;
const DISPATCH_FINISHED_PARTICLES: u32 = 6u;
const DISPATCH_FINISHED_SPRINGS: u32 = 9u;
const DISPATCH_WORDS: u32 = 12u;

// The floor of δ's target as a share of what the f32 state resolves of b (cg_begin): the
// residual's norm stays below 3% of that resolution, so that the solve's own error is not
// what moves a body. At 1 the 6³ stiff cube of tests/stiff_cube.rs rested with 1,100 times
// the kinetic energy of an unfloored solve and the stiff 10³ cube (twins.rs,
// `implicit_solves_stop_at_what_the_f32_state_resolves`) did not come to rest in 2 s, taking
// 77 iterations a step; at 1e-3 they rest as unfloored (2.9e-13 J against 2.0e-13 J), in 39%
// and 38% of the iterations.
const RESOLVED: f32 = 1e-3;

@group(0) @binding(2) var<storage, read> z: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> dv: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> rhs: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read> q: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> r: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read_write> c: array<vec4<f32>>;
@group(0) @binding(8) var<storage, read> diag: array<vec4<f32>>;
@group(0) @binding(10) var<storage, read_write> scalars: CgScalars;
@group(0) @binding(11) var<storage, read_write> dispatch: array<u32, DISPATCH_WORDS>;
@group(0) @binding(12) var<storage, read> mass: array<vec2<f32>>;
// The Δv of the two steps before the last one's (implicit_euler.wgsl's `implicit_remember`
// keeps them): the warm start's history.
@group(0) @binding(1) var<storage, read> earlier_1: array<vec4<f32>>;
@group(0) @binding(9) var<storage, read> earlier_2: array<vec4<f32>>;

// P⁻¹_i p (the symmetric inverse block of system.wgsl).
fn precondition(i: u32, p: vec3<f32>) -> vec3<f32> {
    let d = diag[2u * i].xyz;
    let o = diag[2u * i + 1u].xyz;
    return vec3<f32>(
        d.x * p.x + o.x * p.y + o.y * p.z,
        o.x * p.x + d.y * p.y + o.z * p.z,
        o.y * p.x + o.z * p.y + d.z * p.z,
    );
}

fn vec4_of(p: vec3<f32>) -> vec4<f32> {
    return vec4<f32>(p, 0.0);
}

// Where half `which` of `partials` starts (cg_common.wgsl).
fn half(which: u32) -> u32 {
    return which * scalars.n_partials;
}

// Writes the tree sum of this workgroup's terms to its partial slot in half `which`.
fn write_partial(id: Invocation, term: vec2<f32>, which: u32) {
    write_partial_at(id, term, half(which));
}

var<workgroup> solve_done: u32;

// Whether the solve has stopped, uniformly across the workgroup (so that a kernel dispatched
// directly can return before its barriers).
fn stopped(local: u32) -> bool {
    if local == 0u {
        solve_done = scalars.done;
    }
    return workgroupUniformLoad(&solve_done) != 0u;
}

// The sum of the partials of half `which`, in order: thread t adds partials t, t + 256, … in
// turn, then the tree adds the 256 running sums. Every thread of the workgroup gets the total.
fn sum_in_order(local: u32, which: u32) -> vec2<f32> {
    var acc = vec2<f32>(0.0);
    let start = half(which);
    for (var k = local; k < scalars.n_partials; k += WORKGROUP_SIZE) {
        acc += partials[start + k];
    }
    return workgroup_sum(local, acc);
}

fn set_slot(at: u32, grid: vec2<u32>, on: bool) {
    let g = select(vec3<u32>(0u), vec3<u32>(grid, 1u), on);
    dispatch[at] = g.x;
    dispatch[at + 1u] = g.y;
    dispatch[at + 2u] = g.z;
}

// The iteration kernels' grids while the solve runs; the finished slots once it is done.
fn set_dispatch(done: bool) {
    set_slot(DISPATCH_PARTICLES, scalars.particle_grid, !done);
    set_slot(DISPATCH_SPRINGS, scalars.spring_grid, !done);
    set_slot(DISPATCH_FINISHED_PARTICLES, scalars.particle_grid, done);
    set_slot(DISPATCH_FINISHED_SPRINGS, scalars.spring_grid, done);
}

fn finish(done: bool) {
    scalars.done = select(0u, 1u, done);
    set_dispatch(done);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn cg_start(id: Invocation) {
    let i = thread_of(id);
    var weight = vec2<f32>(0.0);
    if i < params.n_particles {
        dv[i] = vec4_of(free_part(i, dv[i].xyz) + z[i].xyz);
        let w = free_part(i, mass[i].x * (params.dt * params.gravity));
        weight.x = dot(w, free_part(i, precondition(i, w)));
        // ρ_i² tr(S P⁻¹ S): the P⁻¹-norm² of a residual of ρ_i in each free direction.
        var trace = 0.0;
        for (var k = 0u; k < 3u; k++) {
            var e = vec3<f32>(0.0);
            e[k] = 1.0;
            let se = free_part(i, e);
            trace += dot(se, free_part(i, precondition(i, se)));
        }
        weight.y = diag[2u * i + 1u].w * trace;
    }
    write_partial(id, weight, CURVATURE);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn cg_residual(id: Invocation) {
    let i = thread_of(id);
    var term = vec2<f32>(0.0);
    if i < params.n_particles {
        let sb = free_part(i, rhs[i].xyz);
        let ri = free_part(i, rhs[i].xyz - q[i].xyz);
        let ci = free_part(i, precondition(i, ri));
        r[i] = vec4_of(ri);
        c[i] = vec4_of(ci);
        term = vec2<f32>(dot(sb, free_part(i, precondition(i, sb))), dot(ri, ci));
    }
    write_partial(id, term, DELTA);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn cg_begin(id: Invocation) {
    let sums = sum_in_order(id.local, DELTA);
    let start = sum_in_order(id.local, CURVATURE);
    if id.local != 0u {
        return;
    }
    let delta = sums.y;
    let weight = start.x;
    // Relative to the largest of the right-hand side, the warm start's residual and the
    // weight's impulse (see the CPU: a body at rest has S·b ≈ 0), but not below what the f32
    // state resolves of b (`start.y`, Σ ρ_i² tr(S P⁻¹ S)): rounding x to f32 deforms the body
    // by half a ulp every step, and a stiff body's springs turn that into forces CG would
    // otherwise resolve to the tolerance (25–33 iterations a step for a 10³ cube in free fall).
    let scale = max(max(sums.x, delta), weight);
    let target_delta = max(scalars.tolerance * scalars.tolerance * scale, RESOLVED * start.y);
    scalars.delta = delta;
    scalars.scale = scale;
    scalars.target_delta = target_delta;
    scalars.smallest = delta;
    scalars.alpha = 0.0;
    scalars.beta = 0.0;
    scalars.iterations = 0u;
    finish(!(delta > target_delta) || !all_finite(vec3<f32>(delta, scale, 0.0))
        || scalars.max_iterations == 0u);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn cg_advance(id: Invocation) {
    let cq = sum_in_order(id.local, CURVATURE).x;
    // Not usable only through round-off once the residual is at machine precision: then the
    // solve stops with Δv and r as the last iteration left them, as the CPU's does (the partial
    // written is never read).
    let usable = cq > 0.0 && all_finite(vec3<f32>(cq));
    let alpha = scalars.delta / cq;
    if id.local == 0u && workgroup_of(id) == 0u {
        scalars.previous_delta = scalars.delta;
        if usable {
            scalars.alpha = alpha;
        } else {
            scalars.done = 1u;
        }
    }
    let i = thread_of(id);
    var term = vec2<f32>(0.0);
    if usable && i < params.n_particles {
        dv[i] = vec4_of(dv[i].xyz + alpha * c[i].xyz);
        let ri = r[i].xyz - alpha * q[i].xyz;
        r[i] = vec4_of(ri);
        term = vec2<f32>(dot(ri, precondition(i, ri)), 0.0);
    }
    write_partial(id, term, DELTA);
}

// The iteration's scalars from δ' = rᵀP⁻¹r (one thread of cg_direction): whether the solve
// goes on.
fn next_scalars(delta_new: f32, beta: f32) {
    // Round-off dominates once the residual grows by orders of magnitude: stop there.
    if !all_finite(vec3<f32>(delta_new)) || delta_new > 1e6 * scalars.smallest {
        scalars.delta = scalars.smallest;
        finish(true);
        return;
    }
    scalars.smallest = min(scalars.smallest, delta_new);
    scalars.beta = beta;
    scalars.delta = delta_new;
    let iterations = scalars.iterations + 1u;
    scalars.iterations = iterations;
    finish(!(delta_new > scalars.target_delta) || iterations >= scalars.max_iterations);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn cg_direction(id: Invocation) {
    let first = id.local == 0u && workgroup_of(id) == 0u;
    if stopped(id.local) {
        // cg_advance may have stopped the solve in this iteration: it cannot empty the slots.
        if first {
            set_dispatch(true);
        }
        return;
    }
    let delta_new = sum_in_order(id.local, DELTA).x;
    let beta = delta_new / scalars.previous_delta;
    if first {
        next_scalars(delta_new, beta);
    }
    // Once the solve stops here the direction is never read again (the next solve starts
    // with cg_residual's): the other workgroups update it regardless, whether or not they
    // saw `done` set, so the first one's writes race with nothing that matters.
    let i = thread_of(id);
    if i < params.n_particles {
        c[i] = vec4_of(free_part(i, precondition(i, r[i].xyz) + beta * c[i].xyz));
    }
}

// The warm start's projection, the CPU's `project_warm_start` (Fischer's projection for
// successive right-hand sides): with the filtered basis d₀ = S u₀, d₁ = S(u₁ − u₀),
// d₂ = S(u₂ − u₁) of the warm start u₀ (the last solve's Δv) and the Δv u₁, u₂ of the two steps
// before,
//
//   Δv₀ = z + Σ_j x_j d_j,  G x = c,  G_ij = d_iᵀ A d_j,  c_i = d_iᵀ(b − A z)
//
// (the CPU forms c_i as d_iᵀb − (A d_i)ᵀz: the same for a symmetric A; here A z is one product
// of Δv, where z waits while u₀ is kept in r). The host encodes
//
//   cg_project_start:  r = u₀, c = d₀, Δv = z
//   apply_particles(Δv) → q = A z
//   cg_project_rhs:    partials of c_j
//   then for j = 0, 1, 2:
//     apply_particles_curvature(c) → q = S A d_j   (its partial of cᵀq is not used)
//     cg_project_gram_j: partials of G_ij = d_iᵀq for i ≤ j; c = d_{j+1}
//   cg_project_solve:  G x = c by LDLᵀ, dropping nearly dependent directions (one workgroup)
//   cg_project_combine: Δv = Σ_j x_j (u-basis_j), unfiltered, as the CPU's (cg_start filters
//                      it and adds z)
//
// Their sums have halves of `partials` of their own, from PROJECTION on: (c₀, c₁), (c₂, ·), then
// two per row j of G: (G_0j, G_1j), (G_2j, ·) (zero where i > j).
const PROJECTION: u32 = 2u;
const WARM_START_BASIS: u32 = 3u;
// A direction whose pivot is below this fraction of its diagonal entry is left out: in f32 a
// Gram entry's sum carries relative errors of ~1e-7·√(terms) (the CPU's f64 threshold is
// 1e-12).
const INDEPENDENT: f32 = 1e-5;

// Basis vector j of the warm start at particle i, unfiltered: u₀ (in r), u₁ − u₀, u₂ − u₁.
fn warm_basis(j: u32, i: u32) -> vec3<f32> {
    let u0 = r[i].xyz;
    if j == 0u {
        return u0;
    }
    if j == 1u {
        return earlier_1[i].xyz - u0;
    }
    return earlier_2[i].xyz - earlier_1[i].xyz;
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn cg_project_start(id: Invocation) {
    let i = thread_of(id);
    if i < params.n_particles {
        let u0 = dv[i];
        r[i] = u0;
        c[i] = vec4_of(free_part(i, u0.xyz));
        dv[i] = z[i];
    }
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn cg_project_rhs(id: Invocation) {
    let i = thread_of(id);
    var c01 = vec2<f32>(0.0);
    var c2 = vec2<f32>(0.0);
    if i < params.n_particles {
        let w = rhs[i].xyz - q[i].xyz;
        c01 = vec2<f32>(
            dot(free_part(i, warm_basis(0u, i)), w),
            dot(free_part(i, warm_basis(1u, i)), w),
        );
        c2.x = dot(free_part(i, warm_basis(2u, i)), w);
    }
    write_partial(id, c01, PROJECTION);
    write_partial(id, c2, PROJECTION + 1u);
}

// Row j of G from q = S A d_j, and the next basis vector into c.
fn project_gram(id: Invocation, j: u32) {
    let i = thread_of(id);
    var g = array<f32, 3>(0.0, 0.0, 0.0);
    if i < params.n_particles {
        let qi = q[i].xyz;
        for (var k = 0u; k <= j; k++) {
            g[k] = dot(free_part(i, warm_basis(k, i)), qi);
        }
        if j + 1u < WARM_START_BASIS {
            c[i] = vec4_of(free_part(i, warm_basis(j + 1u, i)));
        }
    }
    write_partial(id, vec2<f32>(g[0], g[1]), PROJECTION + 2u + 2u * j);
    write_partial(id, vec2<f32>(g[2], 0.0), PROJECTION + 3u + 2u * j);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn cg_project_gram_0(id: Invocation) {
    project_gram(id, 0u);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn cg_project_gram_1(id: Invocation) {
    project_gram(id, 1u);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn cg_project_gram_2(id: Invocation) {
    project_gram(id, 2u);
}

// G x = c for the Gram matrix of the basis (symmetric positive semi-definite): LDLᵀ, leaving out
// (x_j = 0) each vector whose pivot is below INDEPENDENT of its diagonal entry; non-finite
// coefficients give the plain warm start (x = e₀). The CPU's `solve_gram`, in f32.
@compute @workgroup_size(WORKGROUP_SIZE)
fn cg_project_solve(id: Invocation) {
    let c01 = sum_in_order(id.local, PROJECTION);
    let c2 = sum_in_order(id.local, PROJECTION + 1u).x;
    var gram: array<vec3<f32>, 3>;
    for (var j = 0u; j < WARM_START_BASIS; j++) {
        let upper = sum_in_order(id.local, PROJECTION + 2u + 2u * j);
        let lowest = sum_in_order(id.local, PROJECTION + 3u + 2u * j).x;
        gram[j] = vec3<f32>(upper, lowest); // column j: G_0j, G_1j, G_2j (upper triangle)
    }
    if id.local != 0u {
        return;
    }
    let rhs_c = vec3<f32>(c01, c2);
    var l: array<vec3<f32>, 3>; // l[i][j], i > j
    var pivot = vec3<f32>(0.0);
    var kept = vec3<bool>(false);
    for (var j = 0u; j < WARM_START_BASIS; j++) {
        var v = gram[j][j];
        for (var m = 0u; m < j; m++) {
            v -= l[j][m] * l[j][m] * pivot[m];
        }
        if !(all_finite(vec3<f32>(v)) && v > INDEPENDENT * gram[j][j]) {
            continue;
        }
        kept[j] = true;
        pivot[j] = v;
        for (var i = j + 1u; i < WARM_START_BASIS; i++) {
            var s = gram[i][j]; // G_ji = G_ij, upper triangle: column i, row j
            for (var m = 0u; m < j; m++) {
                s -= l[i][m] * l[j][m] * pivot[m];
            }
            l[i][j] = s / v;
        }
    }
    var y = vec3<f32>(0.0);
    for (var j = 0u; j < WARM_START_BASIS; j++) {
        if kept[j] {
            var s = rhs_c[j];
            for (var m = 0u; m < j; m++) {
                s -= l[j][m] * y[m];
            }
            y[j] = s;
        }
    }
    var x = vec3<f32>(0.0);
    for (var k = 0u; k < WARM_START_BASIS; k++) {
        let j = WARM_START_BASIS - 1u - k;
        if kept[j] {
            var s = y[j] / pivot[j];
            for (var i = j + 1u; i < WARM_START_BASIS; i++) {
                s -= l[i][j] * x[i];
            }
            x[j] = s;
        }
    }
    if !all_finite(x) {
        x = vec3<f32>(1.0, 0.0, 0.0);
    }
    scalars.warm_start = array<f32, 3>(x.x, x.y, x.z);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn cg_project_combine(id: Invocation) {
    let i = thread_of(id);
    if i < params.n_particles {
        var x = scalars.warm_start;
        var sum = vec3<f32>(0.0);
        for (var j = 0u; j < WARM_START_BASIS; j++) {
            sum += x[j] * warm_basis(j, i);
        }
        dv[i] = vec4_of(sum);
    }
}
