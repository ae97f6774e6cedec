// Copyright 2026 physdyn_ros maintainers
//
// Licensed under the Apache License, Version 2.0 (the "License");
// you may not use this file except in compliance with the License.
// You may obtain a copy of the License at
//
//     http://www.apache.org/licenses/LICENSE-2.0
//
// Unless required by applicable law or agreed to in writing, software
// distributed under the License is distributed on an "AS IS" BASIS,
// WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
// See the License for the specific language governing permissions and
// limitations under the License.

// The LSTM cell's elementwise step of the bf16 batched roll-out (physdyn_ros/learn/kernels.py's
// bf16_lstm_rollout) in one pass per row: the bf16 gate pre-activations a product left (gates i, f, o, g, the g
// columns doubled) widened to float32, their sigmoids, the cell state (stored as c' = -2 c, float32) and the new
// hidden state rounded to bf16 (round to nearest even, as torch rounds) for the next products. In torch the same
// step is seven passes over the gates; here it is one, in AVX-512 with the bf16 conversion instructions.
// Built by CMakeLists.txt into the C kernels' library when the compiler has -mavx512bf16; learn/cell_bf16.py calls
// it only where the CPU reports avx512f, avx512bw and avx512_bf16. The same roll-out's sliding prior is here too
// (physdyn_prior_add_f32, plain C).

#include <math.h>
#include <stdint.h>

#if defined(__AVX512F__) && defined(__AVX512BW__) && defined(__AVX512BF16__)
#include <immintrin.h>
#define PHYSDYN_CELL_BF16 1
#endif

// 1 when built with AVX-512 BF16 (physdyn_lstm_cell_bf16 works), else 0.
int physdyn_cell_bf16_simd(void) {
#ifdef PHYSDYN_CELL_BF16
  return 1;
#else
  return 0;
#endif
}

#ifdef PHYSDYN_CELL_BF16
// exp(x) for x in [-87.3, 88.7] (inputs are clamped there): x = n ln2 + r with |r| <= ln2 / 2 (ln2 in two parts)
// and a degree-6 polynomial for exp(r), within 2 ulp of float32 exp: the gates' sigmoids then agree with torch's
// to about 1e-7.
static inline __m512 exp512(__m512 x) {
  x = _mm512_min_ps(_mm512_max_ps(x, _mm512_set1_ps(-87.3f)), _mm512_set1_ps(88.7f));
  const __m512 n = _mm512_roundscale_ps(_mm512_mul_ps(x, _mm512_set1_ps(1.44269504088896341f)),
                                        _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
  __m512 r = _mm512_fnmadd_ps(n, _mm512_set1_ps(0.693359375f), x);
  r = _mm512_fnmadd_ps(n, _mm512_set1_ps(-2.12194440e-4f), r);
  __m512 p = _mm512_set1_ps(1.9875691500e-4f);
  p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(1.3981999507e-3f));
  p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(8.3334519073e-3f));
  p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(4.1665795894e-2f));
  p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(1.6666665459e-1f));
  p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(5.0000001201e-1f));
  p = _mm512_fmadd_ps(p, _mm512_mul_ps(r, r), _mm512_add_ps(r, _mm512_set1_ps(1.0f)));
  // p 2^n by adding n to p's exponent (n in [-126, 128] after the clamp, p in [0.7, 1.5])
  const __m512i e = _mm512_slli_epi32(_mm512_cvtps_epi32(n), 23);
  return _mm512_castsi512_ps(_mm512_add_epi32(_mm512_castps_si512(p), e));
}

static inline __m512 sigmoid512(__m512 x) {
  // 1 / d by the 14-bit reciprocal and one Newton step (2^-28 relative: float32's rounding), not a division,
  // whose throughput would bound the whole pass
  const __m512 one = _mm512_set1_ps(1.0f);
  const __m512 d = _mm512_add_ps(one, exp512(_mm512_sub_ps(_mm512_setzero_ps(), x)));
  const __m512 r = _mm512_rcp14_ps(d);
  return _mm512_mul_ps(r, _mm512_fnmadd_ps(d, r, _mm512_set1_ps(2.0f)));
}

static inline __m512 load_bf16(const uint16_t *p) {
  const __m256i raw = _mm256_loadu_si256((const __m256i *)p);
  return _mm512_castsi512_ps(_mm512_slli_epi32(_mm512_cvtepu16_epi32(raw), 16));
}
#endif

// One cell step over `rows` rows: gates (rows x 4 hidden, bf16, row stride g_stride elements), the cell state c'
// (rows x hidden, float32, row stride c_stride, updated in place) and the new hidden state h (rows x hidden, bf16,
// row stride h_stride). hidden must be a multiple of 16. Returns 0, or -1 (not built with AVX-512 BF16, or a
// hidden size it cannot take) having written nothing.
int physdyn_lstm_cell_bf16(const uint16_t *gates, int64_t g_stride, float *c, int64_t c_stride, uint16_t *h,
                           int64_t h_stride, int64_t rows, int64_t hidden) {
#ifdef PHYSDYN_CELL_BF16
  if (hidden <= 0 || hidden % 16) return -1;
  const __m512 two = _mm512_set1_ps(2.0f), minus_two = _mm512_set1_ps(-2.0f), minus_four = _mm512_set1_ps(-4.0f);
  for (int64_t r = 0; r < rows; ++r) {
    const uint16_t *g = gates + r * g_stride;
    float *cr = c + r * c_stride;
    uint16_t *hr = h + r * h_stride;
    _Pragma("GCC unroll 2")
    for (int64_t j = 0; j < hidden; j += 16) {
      const __m512 si = sigmoid512(load_bf16(g + j));
      const __m512 sf = sigmoid512(load_bf16(g + hidden + j));
      const __m512 so = sigmoid512(load_bf16(g + 2 * hidden + j));
      const __m512 sg = sigmoid512(load_bf16(g + 3 * hidden + j));
      // c' f - 4 i g + 2 i, in the order of torch's c.mul_(f).addcmul_(i, g, value=-4).add_(i, alpha=2)
      __m512 cn = _mm512_mul_ps(_mm512_loadu_ps(cr + j), sf);
      cn = _mm512_add_ps(cn, _mm512_mul_ps(minus_four, _mm512_mul_ps(si, sg)));
      cn = _mm512_add_ps(cn, _mm512_mul_ps(two, si));
      _mm512_storeu_ps(cr + j, cn);
      // h = o tanh(c) = o - 2 o sigmoid(c')
      const __m512 hv = _mm512_add_ps(so, _mm512_mul_ps(minus_two, _mm512_mul_ps(so, sigmoid512(cn))));
      _mm256_storeu_si256((__m256i *)(hr + j), (__m256i)_mm512_cvtneps_pbh(hv));
    }
  }
  return 0;
#else
  (void)gates; (void)g_stride; (void)c; (void)c_stride; (void)h; (void)h_stride; (void)rows; (void)hidden;
  return -1;
#endif
}

// learn/prior.py's prior_raw (sliding_step in the network's normalised spaces) added to one step's outputs:
// y[r, 0:12] += prior(x[r, 0:6]) for each row r, in float32 and in the order of torch's operations there (the
// TorchScript call costs 150 us a step at 1024 rows, this loop a few). sqrtf is correctly rounded, where torch's
// float32 sqrt may differ by one ulp; NaN propagates as through torch's clamps. prior (rows, 3, row stride
// p_stride): mu g, the spin deceleration and the coupling (0 or 1) of each row; scale_in (6), scale_out (12 or
// more); dt in seconds. Only the six components sliding moves are non-zero; the others add 0.
// torch's clamp_min and minimum against a constant: a NaN stays NaN (fmaxf / fminf would drop it)
static inline float clamp_min_nan(float v, float lo) { return v != v || v > lo ? v : lo; }
static inline float min_nan(float v, float hi) { return v != v || v < hi ? v : hi; }

void physdyn_prior_add_f32(const float *x, int64_t x_stride, const float *prior, int64_t p_stride,
                           const float *scale_in, const float *scale_out, float dt, float *y, int64_t y_stride,
                           int64_t rows) {
  for (int64_t r = 0; r < rows; ++r) {
    const float *xr = x + r * x_stride, *pr = prior + r * p_stride;
    float *yr = y + r * y_stride;
    const float decel = pr[0], spin = pr[1], c = pr[2];
    const float vx = xr[0] * scale_in[0], vy = xr[1] * scale_in[1], wz = xr[5] * scale_in[5];
    const float speed = sqrtf((vx * vx + vy * vy) + 1e-12f);
    const float w_abs = fabsf(wz), on = c > 0.0f ? 1.0f : 0.0f;
    const float lever_w = c * decel / clamp_min_nan(spin, 1e-9f) * w_abs;
    const float norm = sqrtf(speed * speed + lever_w * lever_w);
    const float a = decel * ((1.0f - on) + on * speed / norm);
    const float alpha = spin * ((1.0f - on) + on * lever_w / norm);
    const float dx = vx / speed, dy = vy / speed;
    const float t_slide = min_nan(speed / clamp_min_nan(a, 1e-9f), dt);
    const float dist = speed * t_slide - 0.5f * a * t_slide * t_slide;
    const float slow = clamp_min_nan(speed - a * dt, 0.0f);
    const float sign = wz > 0.0f ? 1.0f : (wz < 0.0f ? -1.0f : 0.0f);  // 0 for 0 and NaN, as torch.sign
    const float t_spin = min_nan(w_abs / clamp_min_nan(alpha, 1e-9f), dt);
    const float d_yaw = sign * (w_abs * t_spin - 0.5f * alpha * t_spin * t_spin);
    const float d_wz = sign * clamp_min_nan(w_abs - alpha * dt, 0.0f) - wz;
    // columns: d_vel (0:3), d_angvel (3:6), d_pos (6:9), d_rot (9:12)
    const float out[12] = {slow * dx - vx, slow * dy - vy, 0.0f, 0.0f, 0.0f, d_wz,
                           dist * dx, dist * dy, 0.0f, 0.0f, 0.0f, d_yaw};
    for (int j = 0; j < 12; ++j) yr[j] += out[j] / scale_out[j];
  }
}
