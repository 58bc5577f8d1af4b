
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
