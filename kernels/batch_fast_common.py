"""Helpers of the "fast" batch kernels (kernels/batch_fast*.py): shared arrays and native loads."""

import warp as wp

from .batch_explicit import _C_TYPES, _native
from .forces import EPS_LENGTH

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


# -- the "fast" kernel: the same step with fewer instructions (CUDA only) -------------------------
# Versus press_kernel_cuda: an approximate reciprocal square root for each spring's length and
# its inverse (one MUFU.RSQ where sqrt.rn and div.rn took ~20 instructions); per free vertex dt/m
# and the negated anchor constants precomputed (no division a step); each CSR entry adds its
# spring's force times +-1 without a branch; the probe's bookkeeping without float64 sqrt and
# division (the peak compared as a squared magnitude, the ramp fraction by a reciprocal); shared
# arrays sized to this batch's largest free-vertex and spring counts; a spring's two local ends
# packed in one register. Results differ from the CPU's by rounding (forces within 5e-6 relative, by
# scripts/check_batch_bits.py and tests/test_batch.py); a run repeats its bits on one device.

EPS_LENGTH2 = EPS_LENGTH * EPS_LENGTH


def _shared_array(name, dtype, capacity):
    # a block's working array with no global fallback (__shared__ on CUDA; a static buffer on the
    # CPU, where blocks run one after another): for types no kernel argument has
    ctype = _C_TYPES[dtype]
    snippet = f"""
#if defined(__CUDA_ARCH__)
    __shared__ __align__(16) {ctype} buf[{capacity}];
    return wp::array_t<{ctype}>(buf, {capacity});
#else
    alignas(16) static unsigned char raw[sizeof({ctype}) * {capacity}];
    return wp::array_t<{ctype}>(reinterpret_cast<{ctype}*>(raw), {capacity});
#endif
"""

    @_native.func_native(snippet, f"shared_{name}_{capacity}")
    def stub() -> wp.array(dtype=dtype): ...

    return stub


@wp.func_native(
    """
#if defined(__CUDA_ARCH__)
    return rsqrtf(x);  // MUFU.RSQ: ~2 ulp
#else
    return 1.0f / sqrtf(x);
#endif
"""
)
def rsqrt_approx(x: float) -> float: ...


@wp.func_native(
    """
    const int e = (c > 0 ? c : -c) - 1;
    const float s = c > 0 ? 1.0f : -1.0f;  // exact: f + s * v is f + v or f - v
#if defined(__CUDA_ARCH__)
    const float4 v = reinterpret_cast<const float4*>(a.data)[e];
    return wp::vec_t<3, wp::float32>(fmaf(s, v.x, f[0]), fmaf(s, v.y, f[1]), fmaf(s, v.z, f[2]));
#else
    const wp::vec_t<4, wp::float32>& v = a.data[e];
    return wp::vec_t<3, wp::float32>(f[0] + s * v[0], f[1] + s * v[1], f[2] + s * v[2]);
#endif
"""
)
def add_entry(f: wp.vec3, a: wp.array(dtype=wp.vec4), c: int) -> wp.vec3: ...


@wp.func_native(
    """
    const int c = code.data[k];
    const int e = (c > 0 ? c : -c) - 1;
    const float s = c > 0 ? 1.0f : -1.0f;  // exact: f + s * v is f + v or f - v
#if defined(__CUDA_ARCH__)
    const float4 v = reinterpret_cast<const float4*>(a.data)[e];
    return wp::vec_t<3, wp::float32>(fmaf(s, v.x, f[0]), fmaf(s, v.y, f[1]), fmaf(s, v.z, f[2]));
#else
    const wp::vec_t<4, wp::float32>& v = a.data[e];
    return wp::vec_t<3, wp::float32>(f[0] + s * v[0], f[1] + s * v[1], f[2] + s * v[2]);
#endif
"""
)
def add_entry16(f: wp.vec3, a: wp.array(dtype=wp.vec4), code: wp.array(dtype=wp.int16), k: int) -> wp.vec3: ...


@wp.func_native(
    """
#if defined(__CUDA_ARCH__)
    const float4 v = reinterpret_cast<const float4*>(a.data)[i];
    return wp::vec_t<4, wp::float32>(v.x, v.y, v.z, v.w);
#else
    return a.data[i];
#endif
"""
)
def load4(a: wp.array(dtype=wp.vec4), i: int) -> wp.vec4: ...


@wp.func_native(
    """
#if defined(__CUDA_ARCH__)
    const float2 v = reinterpret_cast<const float2*>(a.data)[i];  // one 8-byte shared load
    return wp::vec_t<2, wp::float32>(v.x, v.y);
#else
    return a.data[i];
#endif
"""
)
def load2(a: wp.array(dtype=wp.vec2), i: int) -> wp.vec2: ...


def shared_bytes_fast(vertex_capacity: int, free_capacity: int, entry_capacity: int, spring_capacity: int, lean: int = 2, max_degree: int = 16) -> int:
    """Shared memory a block of the "fast" kernel takes [bytes]."""
    if int(lean) >= 4:  # codes transposed: max_degree rows of free_capacity (lean 6: two slot maps)
        maps = 4 * spring_capacity if int(lean) == 6 else 4
        if int(lean) in (9, 10):  # the spring slots kept in shared memory; vertex constants only for vertices 64 and up
            maps += 16 * (spring_capacity if int(lean) == 10 else 64) - 24 * min(free_capacity, 64)
        if int(lean) == 11:  # slot maps, cells, masks, 32 spare slots
            maps += 2 * spring_capacity + 2 * (spring_capacity + 32) + 4 * spring_capacity + 4 * (free_capacity // 8 + 1) * max_degree + 16 * 32 + 4
        return 32 * vertex_capacity + 24 * free_capacity + 2 * (free_capacity + 1 + max_degree * free_capacity) + 16 * spring_capacity + 112 + maps
    return 32 * vertex_capacity + 24 * free_capacity + 2 * (free_capacity + 1 + entry_capacity) + 16 * spring_capacity + 112


@wp.func_native(
    """
#if defined(__CUDA_ARCH__)
    int r;
    asm volatile("mov.b32 %0, %1;" : "=r"(r) : "r"(x));  // opaque: nothing derived from x is hoisted out of the step loop
    return r;
#else
    return x;
#endif
"""
)
def opaque(x: int) -> int: ...
