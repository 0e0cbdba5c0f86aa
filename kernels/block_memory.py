"""A block's working memory for the batch kernels: shared arrays, the block barrier, vector loads.

On CUDA a palpation's region lives in shared memory for a whole launch; these native snippets
declare the __shared__ buffers and give Warp an array view of them. On the CPU a block's threads
run as fibers one block after another, so a static buffer plays the part of shared memory and
`block_sync` is the fibers' barrier (`cpu_blocks` turns Warp's CPU blocks on for one launch).
"""

import contextlib

import warp as wp

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})

SHARED_BYTES_MAX = 40 * 1024
"""Working arrays larger than this per block stay in global memory (static shared memory is 48 KiB)."""

C_TYPES = {wp.vec3: "wp::vec_t<3, wp::float32>", wp.vec4: "wp::vec_t<4, wp::float32>", wp.float32: "wp::float32", wp.int32: "wp::int32",
           wp.int16: "wp::int16", wp.float64: "wp::float64", wp.vec2: "wp::vec_t<2, wp::float32>"}
"""The C++ type of each Warp type a working array may hold."""


class NamedNative:
    """``@named.func_native(snippet, name)``: wp.func_native under a name of our choosing.

    Warp keys a function by its qualified name and recognizes a native stub by a decorator
    spelled ``*.func_native(...)``; the working arrays differ per capacity, so each needs its
    own name (and its own __shared__ buffer).
    """

    @staticmethod
    def func_native(snippet, name):
        def decorate(f):
            f.__name__ = f.__qualname__ = name
            return wp.func_native(snippet)(f)

        return decorate


named = NamedNative()


def work_array(name, dtype, capacity, shared):
    """An array view of a block's working storage: __shared__ on CUDA when `shared`, else the slice of
    the `fallback` array at `offset` (the stub's arguments)."""
    ctype = C_TYPES[dtype]
    snippet = f"""
#if defined(__CUDA_ARCH__) && {int(bool(shared))}
    __shared__ __align__(16) {ctype} buf[{capacity}];
    return wp::array_t<{ctype}>(buf, {capacity});
#elif {int(bool(shared))}
    // CPU: blocks run one after another and a block's fibers share this (plain bytes: no static-init guard)
    alignas(16) static unsigned char raw[sizeof({ctype}) * {capacity}];
    return wp::array_t<{ctype}>(reinterpret_cast<{ctype}*>(raw), {capacity});
#else
    return wp::array_t<{ctype}>(fallback.data + offset, {capacity});
#endif
"""

    @named.func_native(snippet, f"work_{name}_{capacity}_{int(bool(shared))}")
    def stub(fallback: wp.array(dtype=dtype), offset: int) -> wp.array(dtype=dtype): ...

    return stub


def shared_array(name, dtype, capacity):
    """A block's working array with no global fallback (__shared__ on CUDA; a static buffer on the
    CPU, where blocks run one after another): for types no kernel argument has."""
    ctype = C_TYPES[dtype]
    snippet = f"""
#if defined(__CUDA_ARCH__)
    __shared__ __align__(16) {ctype} buf[{capacity}];
    return wp::array_t<{ctype}>(buf, {capacity});
#else
    alignas(16) static unsigned char raw[sizeof({ctype}) * {capacity}];
    return wp::array_t<{ctype}>(reinterpret_cast<{ctype}*>(raw), {capacity});
#endif
"""

    @named.func_native(snippet, f"shared_{name}_{capacity}")
    def stub() -> wp.array(dtype=dtype): ...

    return stub


@wp.func_native(
    """
#if defined(__CUDA_ARCH__)
    __syncthreads();
#else
    ::wp::tile_sync<WP_TILE_BLOCK_DIM>();  // a barrier of the block's fibers (none when a block is one thread)
#endif
"""
)
def block_sync(): ...


@contextlib.contextmanager
def cpu_blocks(device):
    """On the CPU a block of several threads runs as fibers with a real barrier only while Warp's
    enable_cpu_blocks is on (off by default: its block_dim would otherwise be 1, with no barrier).
    Switched on for one launch, and back, so no other launch sees it."""
    if not device.is_cpu:
        yield
        return
    saved = wp.config.enable_cpu_blocks
    wp.config.enable_cpu_blocks = True
    try:
        yield
    finally:
        wp.config.enable_cpu_blocks = saved


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


@wp.func_native(
    """
#if defined(__CUDA_ARCH__)
    const float4 v = reinterpret_cast<const float4*>(a.data)[i];  // one 16-byte shared load
    return wp::vec_t<3, wp::float32>(v.x, v.y, v.z);
#else
    const wp::vec_t<4, wp::float32>& v = a.data[i];
    return wp::vec_t<3, wp::float32>(v[0], v[1], v[2]);
#endif
"""
)
def load_xyz(a: wp.array(dtype=wp.vec4), i: int) -> wp.vec3: ...


@wp.func_native(
    """
#if defined(__CUDA_ARCH__)
    reinterpret_cast<float4*>(a.data)[i] = make_float4(v[0], v[1], v[2], 0.0f);  // one 16-byte store
#else
    a.data[i] = wp::vec_t<4, wp::float32>(v[0], v[1], v[2], 0.0f);
#endif
"""
)
def store_xyz(a: wp.array(dtype=wp.vec4), i: int, v: wp.vec3): ...
