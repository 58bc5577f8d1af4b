"""Fused CPU kernels: the inference-time fusion of one query against many references, and
farthest point sampling on SO(3) (the inner loop of fast retrieval's rotation stage).

The eager PyTorch fusion (:func:`helpers.net.model._fuse_block`) runs five or six
element-wise passes over each (references x C x X) block and pays Python
dispatch per small block; on CPU it reaches 1-3 % of the machine's GEMM rate
(``benchmarks/README.md``). This kernel does the same arithmetic in two
passes over each reference, in cache:

1. ``p = q * r_j`` (float16 references converted with F16C when the compiler
   targets it) and the logits ``l_k(x) = sum_c W[k, c] p[c, x] + b[k]``;
2. the normalised fusion weights ``a(x)`` (stable softmax of the variant's
   log-weights, as :meth:`helpers.net.model.Fusion.log_weights`) and
   ``v[c] = sum_x a(x) p[c, x]``,

parallel over references with torch's intra-op threads (each reference is
computed by one thread, so results do not depend on the thread count).
``fuse`` does one level for a block of references; ``fuse_levels`` does every
level of each reference in one call and reads the references it is given by
row index in place (a whole memory-mapped bank, no gathered copy): one Python
call per query instead of one per level, which is what made small scoring calls
(the coarse-to-fine search's rounds) pay more for overhead than for arithmetic.
The weighted sum of pass 2 runs four channels at a time (independent sums).

It is built on first use with ``torch.utils.cpp_extension.load_inline`` (gcc
and ninja, about 30 s once per machine) into ``<cache>/ext/<hash>`` and
loaded from there afterwards. Importing this module builds nothing. If the
build fails (no compiler, no ninja) or ``HELPERS_FUSION_KERNEL=0`` is set,
:func:`get` returns None and callers use the eager path; :func:`status`
says which and why. Inference only: there is no backward. ``fps`` returns exactly the
indices of the numpy loop in :func:`helpers.core.rotations.farthest_point_sampling`.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import platform
import socket
import threading
import time
import warnings
from pathlib import Path
from typing import Any

from ..core.paths import cache_dir

#: log-weight rule per fusion variant (see helpers.net.model.Fusion.log_weights).
MODES = {"adaptive": 0, "sigmoid": 1, "softmax": 2}

_SOURCE = r"""
#include <torch/extension.h>
#include <ATen/Parallel.h>
#include <cmath>
#include <cstring>
#include <vector>
#if defined(__F16C__)
#include <immintrin.h>
#endif

// n values -> float32 (F16C for 8 halves at a time when available).
static inline void to_float(const at::Half* src, float* dst, int64_t n) {
  int64_t i = 0;
#if defined(__F16C__)
  for (; i + 8 <= n; i += 8)
    _mm256_storeu_ps(dst + i, _mm256_cvtph_ps(_mm_loadu_si128(reinterpret_cast<const __m128i*>(src + i))));
#endif
  for (; i < n; ++i) dst[i] = static_cast<float>(src[i]);
}
static inline void to_float(const float* src, float* dst, int64_t n) { std::memcpy(dst, src, n * sizeof(float)); }

static inline float log_sigmoid(float l) {
  return l < 0.f ? l - std::log1p(std::exp(l)) : -std::log1p(std::exp(-l));
}

// One pair at one level: query level block q[c * sq + x] (C x X), reference level block
// rj[c * sc + x]; writes oj[c] = sum_x a(x) q[c, x] r[c, x]. Scratch: lg (K*X), a (X), p (C*X).
template <int K, typename T>
static inline void fuse_pair(const float* q, int64_t sq, const T* rj, int64_t sc, const float* w, const float* b,
                             float* oj, int64_t C, int64_t X, int64_t mode, float* lg, float* a, float* p) {
  for (int64_t c = 0; c < C; ++c) to_float(rj + c * sc, p + c * X, X);
  // Pass 1: local similarity p = q * r_j (kept for pass 2) and the logits.
  for (int64_t k = 0; k < K; ++k)
    for (int64_t x = 0; x < X; ++x) lg[k * X + x] = b[k];
  float* l0 = lg;
  float* l1 = lg + (K > 1 ? X : 0);
  for (int64_t c = 0; c < C; ++c) {
    float* pc = p + c * X;
    const float* qc = q + c * sq;
    const float w0 = w[c];
    const float w1 = K > 1 ? w[C + c] : 0.f;
    for (int64_t x = 0; x < X; ++x) {
      const float v = pc[x] * qc[x];
      pc[x] = v;
      l0[x] += w0 * v;
      if (K > 1) l1[x] += w1 * v;
    }
  }
  // Fusion weights: softmax over x of the variant's log-weights, max subtracted.
  float m = 0.f;
  for (int64_t x = 0; x < X; ++x) {
    float v;
    if (mode == 0) v = l1[x] + log_sigmoid(l0[x]);
    else if (mode == 1) v = log_sigmoid(l0[x]);
    else v = l0[x];
    a[x] = v;
    m = (x == 0 || v > m) ? v : m;
  }
  float s = 0.f;
  for (int64_t x = 0; x < X; ++x) { a[x] = std::exp(a[x] - m); s += a[x]; }
  const float inv = 1.f / s;
  for (int64_t x = 0; x < X; ++x) a[x] *= inv;
  // Pass 2: weighted sum over locations, four channels at a time (four independent sums,
  // so the adds do not wait on one another; a(x) is loaded once for the four).
  int64_t c = 0;
  for (; c + 4 <= C; c += 4) {
    const float* p0 = p + c * X;
    const float* p1 = p0 + X;
    const float* p2 = p1 + X;
    const float* p3 = p2 + X;
    float s0 = 0.f, s1 = 0.f, s2 = 0.f, s3 = 0.f;
    for (int64_t x = 0; x < X; ++x) {
      const float ax = a[x];
      s0 += p0[x] * ax; s1 += p1[x] * ax; s2 += p2[x] * ax; s3 += p3[x] * ax;
    }
    oj[c] = s0; oj[c + 1] = s1; oj[c + 2] = s2; oj[c + 3] = s3;
  }
  for (; c < C; ++c) {
    const float* pc = p + c * X;
    float acc = 0.f;
    for (int64_t x = 0; x < X; ++x) acc += pc[x] * a[x];
    oj[c] = acc;
  }
}

// q (C, X) contiguous float; reference j, channel c, location x at r[j*sj + c*sc + off + x].
// out (R, C): out[j, c] = sum_x a_j(x) q[c, x] r_j[c, x].
template <int K, typename T>
static void fuse_impl(const float* q, const T* r, int64_t sj, int64_t sc, int64_t off,
                      const float* w, const float* b, float* out,
                      int64_t R, int64_t C, int64_t X, int64_t mode) {
  at::parallel_for(0, R, 1, [&](int64_t j0, int64_t j1) {
    std::vector<float> lg(K * X), a(X), p(C * X);
    for (int64_t j = j0; j < j1; ++j)
      fuse_pair<K, T>(q, X, r + j * sj + off, sc, w, b, out + j * C, C, X, mode, lg.data(), a.data(), p.data());
  });
}

template <typename T>
static void dispatch_k(int64_t K, const float* q, const T* r, int64_t sj, int64_t sc, int64_t off,
                       const float* w, const float* b, float* out, int64_t R, int64_t C, int64_t X, int64_t mode) {
  if (K == 2) fuse_impl<2, T>(q, r, sj, sc, off, w, b, out, R, C, X, mode);
  else fuse_impl<1, T>(q, r, sj, sc, off, w, b, out, R, C, X, mode);
}

torch::Tensor fuse(torch::Tensor q, torch::Tensor r, int64_t off, int64_t X,
                   torch::Tensor w, torch::Tensor b, int64_t mode) {
  TORCH_CHECK(q.device().is_cpu() && r.device().is_cpu(), "fuse: CPU tensors only");
  TORCH_CHECK(q.dim() == 2 && q.scalar_type() == torch::kFloat && q.is_contiguous(), "fuse: q must be (C,X) float32 contiguous");
  TORCH_CHECK(r.dim() == 3 && r.stride(2) == 1, "fuse: r must be (R,C,L) with unit stride on L");
  TORCH_CHECK(w.dim() == 2 && w.is_contiguous() && w.scalar_type() == torch::kFloat, "fuse: w must be (K,C) float32");
  TORCH_CHECK(b.dim() == 1 && b.is_contiguous() && b.scalar_type() == torch::kFloat, "fuse: b must be (K,) float32");
  const int64_t R = r.size(0), C = r.size(1), K = w.size(0);
  TORCH_CHECK(q.size(0) == C && q.size(1) == X && w.size(1) == C && b.size(0) == K, "fuse: shape mismatch");
  TORCH_CHECK(K == 1 || K == 2, "fuse: K must be 1 or 2");
  TORCH_CHECK(mode >= 0 && mode <= 2 && (mode != 0 || K == 2), "fuse: bad mode");
  TORCH_CHECK(off >= 0 && off + X <= r.size(2), "fuse: level slice out of range");
  auto out = torch::empty({R, C}, q.options());
  if (R == 0) return out;
  if (r.scalar_type() == torch::kHalf)
    dispatch_k<at::Half>(K, q.data_ptr<float>(), r.data_ptr<at::Half>(), r.stride(0), r.stride(1), off,
                         w.data_ptr<float>(), b.data_ptr<float>(), out.data_ptr<float>(), R, C, X, mode);
  else if (r.scalar_type() == torch::kFloat)
    dispatch_k<float>(K, q.data_ptr<float>(), r.data_ptr<float>(), r.stride(0), r.stride(1), off,
                      w.data_ptr<float>(), b.data_ptr<float>(), out.data_ptr<float>(), R, C, X, mode);
  else
    TORCH_CHECK(false, "fuse: r must be float16 or float32");
  return out;
}

// All levels in one call: q (C, L) contiguous float; level i covers locations
// [offs[i], offs[i] + xs[i]) with weights w[i] (K, C) and bias b[i] (K,).
// Row j of the output is reference rows[j] of r (a gather without a copy: r can be a whole
// memory-mapped bank). out (M, n * C), level-major: out[j, i*C + c] = fuse(q level i, r_rows[j] level i)[c].
// Each reference is read by one thread for all its levels (one Python call per query).
template <int K, typename T>
static void fuse_levels_impl(const float* q, int64_t L, const T* r, const int64_t* rows, int64_t sj, int64_t sc,
                             const std::vector<int64_t>& offs, const std::vector<int64_t>& xs,
                             const float* w, const float* b, float* out, int64_t R, int64_t C, int64_t mode) {
  const int64_t n = static_cast<int64_t>(offs.size());
  int64_t xmax = 0;
  for (int64_t x : xs) xmax = x > xmax ? x : xmax;
  at::parallel_for(0, R, 1, [&](int64_t j0, int64_t j1) {
    std::vector<float> lg(K * xmax), a(xmax), p(C * xmax);
    for (int64_t j = j0; j < j1; ++j)
      for (int64_t i = 0; i < n; ++i)
        fuse_pair<K, T>(q + offs[i], L, r + rows[j] * sj + offs[i], sc, w + i * K * C, b + i * K,
                        out + j * n * C + i * C, C, xs[i], mode, lg.data(), a.data(), p.data());
  });
}

template <typename T>
static void dispatch_levels(int64_t K, const float* q, int64_t L, const T* r, const int64_t* rows, int64_t sj,
                            int64_t sc,
                            const std::vector<int64_t>& offs, const std::vector<int64_t>& xs, const float* w,
                            const float* b, float* out, int64_t R, int64_t C, int64_t mode) {
  if (K == 2) fuse_levels_impl<2, T>(q, L, r, rows, sj, sc, offs, xs, w, b, out, R, C, mode);
  else fuse_levels_impl<1, T>(q, L, r, rows, sj, sc, offs, xs, w, b, out, R, C, mode);
}

torch::Tensor fuse_levels(torch::Tensor q, torch::Tensor r, torch::Tensor rows, std::vector<int64_t> offs,
                          std::vector<int64_t> xs, torch::Tensor w, torch::Tensor b, int64_t mode) {
  TORCH_CHECK(q.device().is_cpu() && r.device().is_cpu(), "fuse_levels: CPU tensors only");
  TORCH_CHECK(q.dim() == 2 && q.scalar_type() == torch::kFloat && q.is_contiguous(),
              "fuse_levels: q must be (C,L) float32 contiguous");
  TORCH_CHECK(r.dim() == 3 && r.stride(2) == 1, "fuse_levels: r must be (R,C,L) with unit stride on L");
  TORCH_CHECK(w.dim() == 3 && w.is_contiguous() && w.scalar_type() == torch::kFloat,
              "fuse_levels: w must be (n,K,C) float32 contiguous");
  TORCH_CHECK(b.dim() == 2 && b.is_contiguous() && b.scalar_type() == torch::kFloat,
              "fuse_levels: b must be (n,K) float32 contiguous");
  TORCH_CHECK(rows.dim() == 1 && rows.scalar_type() == torch::kLong && rows.is_contiguous() && rows.device().is_cpu(),
              "fuse_levels: rows must be a (M,) contiguous int64 CPU tensor");
  const int64_t R = rows.size(0), C = r.size(1), L = r.size(2), n = w.size(0), K = w.size(1);
  const int64_t* rw = rows.data_ptr<int64_t>();
  for (int64_t j = 0; j < R; ++j)
    TORCH_CHECK(rw[j] >= 0 && rw[j] < r.size(0), "fuse_levels: row index ", rw[j], " out of range [0, ", r.size(0), ")");
  TORCH_CHECK(q.size(0) == C && q.size(1) == L && w.size(2) == C && b.size(0) == n && b.size(1) == K,
              "fuse_levels: shape mismatch");
  TORCH_CHECK(static_cast<int64_t>(offs.size()) == n && static_cast<int64_t>(xs.size()) == n && n >= 1,
              "fuse_levels: need one offset and one width per level");
  for (int64_t i = 0; i < n; ++i)
    TORCH_CHECK(offs[i] >= 0 && xs[i] >= 1 && offs[i] + xs[i] <= L, "fuse_levels: level slice out of range");
  TORCH_CHECK(K == 1 || K == 2, "fuse_levels: K must be 1 or 2");
  TORCH_CHECK(mode >= 0 && mode <= 2 && (mode != 0 || K == 2), "fuse_levels: bad mode");
  auto out = torch::empty({R, n * C}, q.options());
  if (R == 0) return out;
  if (r.scalar_type() == torch::kHalf)
    dispatch_levels<at::Half>(K, q.data_ptr<float>(), L, r.data_ptr<at::Half>(), rw, r.stride(0), r.stride(1), offs, xs,
                              w.data_ptr<float>(), b.data_ptr<float>(), out.data_ptr<float>(), R, C, mode);
  else if (r.scalar_type() == torch::kFloat)
    dispatch_levels<float>(K, q.data_ptr<float>(), L, r.data_ptr<float>(), rw, r.stride(0), r.stride(1), offs, xs,
                           w.data_ptr<float>(), b.data_ptr<float>(), out.data_ptr<float>(), R, C, mode);
  else
    TORCH_CHECK(false, "fuse_levels: r must be float16 or float32");
  return out;
}

// Greedy farthest point sampling by traces (helpers.core.rotations.farthest_point_sampling):
// layout (9, M) float64 whose entries are multiples of 2^-24, so every trace below is exact in
// any summation order (-ffast-math and FMA cannot change it). Returns k pool positions: start,
// then repeatedly the position whose largest trace to the chosen set is smallest (first on ties).
torch::Tensor fps(torch::Tensor layout, int64_t k, int64_t start) {
  TORCH_CHECK(layout.device().is_cpu() && layout.dim() == 2 && layout.size(0) == 9 &&
              layout.scalar_type() == torch::kDouble && layout.is_contiguous(),
              "fps: layout must be a (9, M) contiguous float64 CPU tensor");
  const int64_t M = layout.size(1);
  TORCH_CHECK(k >= 1 && k <= M && start >= 0 && start < M, "fps: need 1 <= k <= M and 0 <= start < M");
  const double* F = layout.data_ptr<double>();
  std::vector<double> best(M);
  auto out = torch::empty({k}, torch::kLong);
  int64_t* o = out.data_ptr<int64_t>();
  int64_t j = start;
  for (int64_t i = 0; i < k; ++i) {
    o[i] = j;
    if (i + 1 == k) break;
    double v[9];
    for (int c = 0; c < 9; ++c) v[c] = F[c * M + j];
    double* B = best.data();
    const bool first = i == 0;
    for (int64_t m = 0; m < M; ++m) {  // vectorised: one pass over the nine rows
      const double t = F[m] * v[0] + F[M + m] * v[1] + F[2 * M + m] * v[2] + F[3 * M + m] * v[3] +
                       F[4 * M + m] * v[4] + F[5 * M + m] * v[5] + F[6 * M + m] * v[6] +
                       F[7 * M + m] * v[7] + F[8 * M + m] * v[8];
      B[m] = (first || t > B[m]) ? t : B[m];
    }
    double lo = B[0];
    int64_t arg = 0;
    for (int64_t m = 1; m < M; ++m)
      if (B[m] < lo) { lo = B[m]; arg = m; }
    j = arg;
  }
  return out;
}
"""

# -ffast-math lets gcc vectorise the sums (the kernel needs no inf/NaN semantics: the max starts
# from the first value); -fopenmp makes at::parallel_for actually use torch's threads.
_CFLAGS = ["-O3", "-march=native", "-ffast-math", "-fopenmp"]
_LDFLAGS = ["-fopenmp"]

_lock = threading.Lock()
_state: dict[str, Any] = {"module": None, "tried": False, "reason": "not built yet", "build_seconds": None,
                          "build_dir": None}


def _cpu_tag() -> str:
    """Distinguishes machines for -march=native builds (ISA flags of this CPU)."""
    flags = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags"):
                flags = line
                break
    except OSError:
        pass
    return hashlib.sha256(f"{platform.machine()}|{flags}".encode()).hexdigest()[:8]


def build_dir() -> Path:
    """Where the extension is built: ``$HELPERS_EXT_DIR`` or ``<cache>/ext``, then a content hash."""
    import torch

    root = Path(os.environ["HELPERS_EXT_DIR"]) if os.environ.get("HELPERS_EXT_DIR") else cache_dir() / "ext"
    key = hashlib.sha256("|".join([_SOURCE, " ".join(_CFLAGS + _LDFLAGS), torch.__version__, _cpu_tag()]).encode())
    return root / f"fusion_{key.hexdigest()[:16]}"


def _build() -> tuple[Any, Path]:
    """Build (or load an earlier build of) the extension; returns (module, its build folder)."""
    import torch.utils.cpp_extension as ext

    try:
        import ninja  # noqa: F401  (the PyPI wheel ships the binary torch's builder calls)
        ninja_bin = getattr(ninja, "BIN_DIR", None)
    except ImportError:
        ninja_bin = None
    where = build_dir()
    where.mkdir(parents=True, exist_ok=True)
    old_path = os.environ.get("PATH", "")
    if ninja_bin:
        # torch looks ninja up on PATH; a venv used without activation does not have it there.
        os.environ["PATH"] = f"{ninja_bin}{os.pathsep}{old_path}"
    try:
        module = ext.load_inline(name=f"helpers_fusion_{where.name.split('_')[1]}", cpp_sources=_SOURCE,
                                 functions=["fuse", "fuse_levels", "fps"],  # copies: torch appends to the lists it is given
                                 extra_cflags=list(_CFLAGS), extra_ldflags=list(_LDFLAGS),
                                 build_directory=str(where), verbose=False)
        return module, where
    finally:
        os.environ["PATH"] = old_path


BUILD_TIMEOUT_S = 600.0
"""Default for ``$HELPERS_KERNEL_BUILD_TIMEOUT``: the longest a run waits for the kernel (another
process's build, or its own) before it goes on with the eager fusion."""

_LOCK_NAME = "helpers_build.lock"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def _lock_owner(path: Path) -> dict | None:
    """{"pid", "host", "started"} recorded in a build lock, or None if unreadable."""
    try:
        d = json.loads(path.read_text())
        return d if isinstance(d, dict) and "pid" in d else None
    except (OSError, ValueError):
        return None


def _stale(owner: dict | None, path: Path, timeout: float) -> bool:
    """A lock is stale when its process is gone (same host), or, where that cannot be
    checked (another host, unreadable file), when it is older than ``timeout``."""
    if owner is not None and owner.get("host") == socket.gethostname():
        return not _pid_alive(int(owner["pid"]))
    try:
        return time.time() - path.stat().st_mtime > timeout
    except OSError:
        return True


def acquire_build_lock(where: Path, timeout: float, poll: float = 0.5, report_every: float = 30.0) -> bool:
    """Take the build lock of ``where`` (created atomically), clearing stale ones.

    While another live process builds, waits up to ``timeout`` seconds with a
    warning every ``report_every`` seconds naming the process and the lock file.
    Returns False if the lock is still held by a live process after ``timeout``.
    Every process takes this lock before calling torch's builder, so a leftover
    torch ``lock`` file found while holding it is stale and is removed (torch's own
    wait on it has no time limit).
    """
    path = where / _LOCK_NAME
    t0 = last = time.monotonic()
    while True:
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            owner = _lock_owner(path)
            if _stale(owner, path, timeout):
                warnings.warn(f"helpers.net.fusion_kernel: removing stale build lock {path} (owner {owner}: process "
                              "gone)", RuntimeWarning, stacklevel=3)
                with contextlib.suppress(FileNotFoundError):
                    path.unlink()
                continue
            now = time.monotonic()
            if now - t0 >= timeout:
                return False
            if now - last >= report_every:
                warnings.warn(f"helpers.net.fusion_kernel: waiting {now - t0:.0f} s (limit {timeout:.0f} s) for the "
                              f"kernel build of process {owner and owner.get('pid')} on {owner and owner.get('host')} "
                              f"(lock {path})", RuntimeWarning, stacklevel=3)
                last = now
            time.sleep(poll)
            continue
        with os.fdopen(fd, "w") as f:
            json.dump({"pid": os.getpid(), "host": socket.gethostname(), "started": time.time()}, f)
        torch_lock = where / "lock"
        if torch_lock.exists():
            warnings.warn(f"helpers.net.fusion_kernel: removing torch's leftover build lock {torch_lock} "
                          "(from an interrupted build)", RuntimeWarning, stacklevel=3)
            with contextlib.suppress(FileNotFoundError):
                torch_lock.unlink()
        return True


def release_build_lock(where: Path) -> None:
    with contextlib.suppress(FileNotFoundError):
        (where / _LOCK_NAME).unlink()


def _timeout() -> float:
    raw = os.environ.get("HELPERS_KERNEL_BUILD_TIMEOUT", "")
    try:
        return float(raw) if raw.strip() else BUILD_TIMEOUT_S
    except ValueError:
        raise ValueError(f"HELPERS_KERNEL_BUILD_TIMEOUT: expected seconds, got {raw!r}") from None


def _build_limited(timeout: float) -> tuple[Any, Path]:
    """:func:`_build` under the cross-process build lock, the whole of it (waiting for another
    build, then building) limited to ``timeout`` seconds; raises TimeoutError past it."""
    where = build_dir()
    where.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    if not acquire_build_lock(where, timeout):
        owner = _lock_owner(where / _LOCK_NAME)
        raise TimeoutError(f"waited {timeout:.0f} s for the build of process {owner and owner.get('pid')} "
                           f"(lock {where / _LOCK_NAME})")
    result: dict[str, Any] = {}

    def work() -> None:
        try:
            result["value"] = _build()
        except BaseException as e:  # handed to the caller below
            result["error"] = e
        finally:
            release_build_lock(where)

    # A daemon thread so that a compiler that never returns cannot hold the run: past the limit the
    # caller goes on (eager fusion); if the process then exits, the lock it leaves names a dead pid.
    th = threading.Thread(target=work, name="fusion-kernel-build", daemon=True)
    th.start()
    th.join(max(1.0, timeout - (time.monotonic() - t0)))
    if th.is_alive():
        raise TimeoutError(f"the kernel build in {where} did not finish within {timeout:.0f} s")
    if "error" in result:
        raise result["error"]
    return result["value"]


def get() -> Any | None:
    """The compiled module (with ``fuse``), building it on first call; None if unavailable.

    Disabled by ``HELPERS_FUSION_KERNEL=0``. A failed build is reported once
    as a warning and not retried in this process. Builds of several processes are
    serialised by a lock file that names its process; a lock left by a dead process
    is cleared, and waiting plus building is limited to ``$HELPERS_KERNEL_BUILD_TIMEOUT``
    seconds (default :data:`BUILD_TIMEOUT_S`), after which the eager fusion is used
    with a warning.
    """
    if os.environ.get("HELPERS_FUSION_KERNEL", "1").strip().lower() in ("0", "false", "no", "off"):
        _state["reason"] = "disabled by HELPERS_FUSION_KERNEL"
        return None
    if _state["tried"]:
        return _state["module"]
    with _lock:
        if not _state["tried"]:
            t0 = time.perf_counter()
            try:
                module, where = _build_limited(_timeout())
                _state["module"] = module
                _state["reason"] = None
                _state["build_dir"] = str(where)
            except Exception as e:  # compiler, ninja or headers missing: fall back, say why
                _state["module"] = None
                _state["reason"] = f"build failed: {type(e).__name__}: {str(e).splitlines()[0][:300] if str(e) else ''}"
                warnings.warn(f"helpers.net.fusion_kernel: {_state['reason']}; using the eager PyTorch fusion "
                              "and numpy farthest point sampling (slower, same results)", RuntimeWarning, stacklevel=2)
            _state["build_seconds"] = time.perf_counter() - t0
            _state["tried"] = True
    return _state["module"]


def status() -> dict[str, Any]:
    """{"available", "reason" (None when available), "build_seconds" (this process), "build_dir"}."""
    return {"available": _state["module"] is not None, "reason": _state["reason"],
            "build_seconds": _state["build_seconds"], "build_dir": _state["build_dir"]}
