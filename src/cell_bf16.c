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

// The elementwise work of the bf16 batched roll-out (physdyn_ros/learn/cell_bf16.py's c_bf16_lstm_rollout; its
// products stay oneDNN's): the LSTM cell step in one pass per row (the bf16 gate pre-activations a product left,
// gates i, f, o, g with the g columns doubled, widened to float32; their sigmoids; the cell state, stored as
// c' = -2 c in float32; the new hidden state rounded to bf16 for the next products), and after the last layer's
// cell the rest of the step on the same row (the head, the sliding prior, the next input). In torch that is a
// dozen passes and calls per step; here it is one pass per layer, in AVX-512 with the bf16 instructions.
// Built by CMakeLists.txt into the C kernels' library when the compiler has -mavx512bf16; learn/cell_bf16.py calls
// it only where the CPU reports avx512f, avx512bw and avx512_bf16.

#include <math.h>
#include <stdint.h>
#include <string.h>

// The head's outputs per step (kernels.OUT_DIM)
#define TAIL_OUT 13

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
// sigmoid(x) = 1 / (1 + exp(-x)). exp(-x) with x clamped to [-88, 88] (NaN passes): -x = n ln2 + r with
// |r| <= ln2 / 2 (ln2 in two parts), exp(r) = 1 + r + r^2 q(r) with a cubic q fitted for the least maximal relative
// error (2e-7, 3 ulp of float32: far below the bf16 rounding of the gates it is applied to), times 2^n by scalef.
// Then 1 / d by the 14-bit reciprocal and one Newton step (2^-28 relative), not a division, whose throughput would
// bound the whole pass. 17 vector operations.
static inline __m512 sigmoid512(__m512 x) {
  // max and min return their second operand when either is NaN: a NaN gate stays NaN, as in torch
  x = _mm512_min_ps(_mm512_set1_ps(88.0f), _mm512_max_ps(_mm512_set1_ps(-88.0f), x));
  const __m512 n = _mm512_roundscale_ps(_mm512_mul_ps(x, _mm512_set1_ps(-1.44269504088896341f)),
                                        _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
  __m512 r = _mm512_fnmsub_ps(n, _mm512_set1_ps(0.693359375f), x);  // -x - n ln2_hi
  r = _mm512_fnmadd_ps(n, _mm512_set1_ps(-2.12194440e-4f), r);      // - n ln2_lo
  __m512 q = _mm512_set1_ps(8.3337547258e-3f);
  q = _mm512_fmadd_ps(q, r, _mm512_set1_ps(4.1898511350e-2f));
  q = _mm512_fmadd_ps(q, r, _mm512_set1_ps(1.6666887701e-1f));
  q = _mm512_fmadd_ps(q, r, _mm512_set1_ps(4.9999144673e-1f));
  const __m512 one = _mm512_set1_ps(1.0f);
  const __m512 e = _mm512_scalef_ps(_mm512_fmadd_ps(q, _mm512_mul_ps(r, r), _mm512_add_ps(r, one)), n);
  const __m512 d = _mm512_add_ps(one, e);
  const __m512 rc = _mm512_rcp14_ps(d);
  return _mm512_mul_ps(rc, _mm512_fnmadd_ps(d, rc, _mm512_set1_ps(2.0f)));
}

static inline __m512 load_bf16(const uint16_t *p) {
  const __m256i raw = _mm256_loadu_si256((const __m256i *)p);
  return _mm512_castsi512_ps(_mm512_slli_epi32(_mm512_cvtepu16_epi32(raw), 16));
}
#endif

#ifdef PHYSDYN_CELL_BF16
// One row of a cell step: gates g (4 hidden, bf16), the cell state c' (float32, updated in place), the new hidden
// state h (bf16).
static inline void cell_row(const uint16_t *g, float *cr, uint16_t *hr, int64_t hidden) {
  const __m512 two = _mm512_set1_ps(2.0f), minus_two = _mm512_set1_ps(-2.0f), minus_four = _mm512_set1_ps(-4.0f);
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
#endif

// One cell step over `rows` rows: gates (rows x 4 hidden, bf16, row stride g_stride elements), the cell state c'
// (rows x hidden, float32, row stride c_stride, updated in place) and the new hidden state h (rows x hidden, bf16,
// row stride h_stride). hidden must be a multiple of 16. Returns 0, or -1 (not built with AVX-512 BF16, or a
// hidden size it cannot take) having written nothing.
int physdyn_lstm_cell_bf16(const uint16_t *gates, int64_t g_stride, float *c, int64_t c_stride, uint16_t *h,
                           int64_t h_stride, int64_t rows, int64_t hidden) {
#ifdef PHYSDYN_CELL_BF16
  if (hidden <= 0 || hidden % 16) return -1;
  for (int64_t r = 0; r < rows; ++r) cell_row(gates + r * g_stride, c + r * c_stride, h + r * h_stride, hidden);
  return 0;
#else
  (void)gates; (void)g_stride; (void)c; (void)c_stride; (void)h; (void)h_stride; (void)rows; (void)hidden;
  return -1;
#endif
}

// torch's clamp_min and minimum against a constant: a NaN stays NaN (fmaxf / fminf would drop it)
static inline float clamp_min_nan(float v, float lo) { return v != v || v > lo ? v : lo; }
static inline float min_nan(float v, float hi) { return v != v || v < hi ? v : hi; }

// learn/prior.py's prior_raw (sliding_step in the network's normalised spaces) of one row added to its outputs:
// yr[0:12] += prior(xr[0:6]), in float32 and in the order of torch's operations there. sqrtf is correctly
// rounded, where torch's float32 sqrt may differ by one ulp; NaN propagates as through torch's clamps. pr: mu g,
// the spin deceleration and the coupling (0 or 1) of the row; scale_in (6), scale_out (12 or more); dt in seconds.
// Only the six components sliding moves are non-zero; the others add 0.
static inline void prior_row(const float *xr, const float *pr, const float *scale_in, const float *scale_out,
                             float dt, float *yr) {
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

// float32 -> bf16, rounded to nearest even as torch rounds (a NaN stays a quiet NaN; torch's own bits for it vary
// with its code path)
static inline uint16_t bf16_rne(float f) {
  uint32_t u;
  memcpy(&u, &f, sizeof u);
  if ((u & 0x7fffffffu) > 0x7f800000u) return (uint16_t)((u >> 16) | 0x40u);
  u += 0x7fffu + ((u >> 16) & 1u);
  return (uint16_t)(u >> 16);
}

// The rest of a roll-out step after the last layer's cell (c_bf16_lstm_rollout's step tail; in torch a bf16 head
// product and seven small operations), per row: the head y = b_head + x w_skip + h w_out, its products
// accumulated in float32 (AVX-512 BF16 dot products of h's pairs against w_pairs; torch's bf16 product would round
// y to bf16), then the sliding prior where `prior` is given, then the next input: the observed row of x_obs
// where given, else x + y[0:6] gain; it is stored in x (float32), in xs (the inputs' record) and, rounded to bf16,
// in zx (the next products' row buffer). Strides are in elements. learn/cell_bf16.py's Tail mirrors it.
typedef struct {
  const uint16_t *w_pairs;  // (hidden / 2, 16, 2) bf16: w_out[k, j] at [k / 2][j][k % 2], columns 13-15 zero
  const float *w_skip;      // (6, 16): the input skip, columns 13-15 zero; or NULL
  const float *b_head;      // (16), 13-15 zero
  const float *prior;       // (rows, 3, row stride p_stride) as prior_row's pr, or NULL: no prior
  int64_t p_stride;
  const float *scale_in, *scale_out;
  float dt;
  const float *x_obs;  // (rows, 6, row stride obs_stride): this step's observed inputs, or NULL: integrate
  int64_t obs_stride;
  const float *gain;  // (6)
  float *x;           // (rows, 6, row stride x_stride), float32
  int64_t x_stride;
  float *y;  // (rows, 13, row stride y_stride): this step's outputs
  int64_t y_stride;
  float *xs;  // (rows, 6, row stride xs_stride): this step's record of the next input
  int64_t xs_stride;
  uint16_t *zx;  // (rows, 6, row stride z_stride) bf16: the next input in the row buffer
  int64_t z_stride;
} physdyn_tail;

// sizeof(physdyn_tail): learn/cell_bf16.py checks its mirror of the struct against it.
int64_t physdyn_tail_size(void) { return (int64_t)sizeof(physdyn_tail); }

#ifdef PHYSDYN_CELL_BF16
static inline void tail_row(const physdyn_tail *t, const uint16_t *hr, int64_t hidden, int64_t r) {
  float *xr = t->x + r * t->x_stride, *yr = t->y + r * t->y_stride;
  // eight chains of dot products (a pair of h each): one chain would wait on each product's latency
  __m512 acc[8];
  for (int i = 0; i < 8; ++i) acc[i] = _mm512_setzero_ps();
  for (int64_t k = 0; k < hidden; k += 16) {
    for (int i = 0; i < 8; ++i) {
      uint32_t pair;
      memcpy(&pair, hr + k + 2 * i, sizeof pair);
      acc[i] = _mm512_dpbf16_ps(acc[i], (__m512bh)_mm512_set1_epi32((int)pair),
                                (__m512bh)_mm512_loadu_si512(t->w_pairs + (k + 2 * i) * 16));
    }
  }
  const __m512 dots = _mm512_add_ps(_mm512_add_ps(_mm512_add_ps(acc[0], acc[1]), _mm512_add_ps(acc[2], acc[3])),
                                    _mm512_add_ps(_mm512_add_ps(acc[4], acc[5]), _mm512_add_ps(acc[6], acc[7])));
  __m512 s = _mm512_loadu_ps(t->b_head);
  if (t->w_skip)
    for (int k = 0; k < 6; ++k) s = _mm512_fmadd_ps(_mm512_set1_ps(xr[k]), _mm512_loadu_ps(t->w_skip + 16 * k), s);
  _mm512_mask_storeu_ps(yr, (__mmask16)((1u << TAIL_OUT) - 1u), _mm512_add_ps(s, dots));
  if (t->prior) prior_row(xr, t->prior + r * t->p_stride, t->scale_in, t->scale_out, t->dt, yr);
  float *xsr = t->xs + r * t->xs_stride;
  uint16_t *zr = t->zx + r * t->z_stride;
  for (int k = 0; k < 6; ++k) {
    xr[k] = t->x_obs ? t->x_obs[r * t->obs_stride + k] : xr[k] + yr[k] * t->gain[k];
    xsr[k] = xr[k];
    zr[k] = bf16_rne(xr[k]);
  }
}
#endif

// The last layer's cell step (as physdyn_lstm_cell_bf16) and the step tail, row by row: the tail reads each new
// h while it is in the L1 cache (a second pass over the rows would fetch them again from a cache the products
// have filled). Returns 0, or -1 (not built with AVX-512 BF16, or a hidden size that is not a multiple of 16)
// having written nothing.
int physdyn_cell_tail_bf16(const uint16_t *gates, int64_t g_stride, float *c, int64_t c_stride, uint16_t *h,
                           int64_t h_stride, int64_t rows, int64_t hidden, const physdyn_tail *tail) {
#ifdef PHYSDYN_CELL_BF16
  if (hidden <= 0 || hidden % 16) return -1;
  for (int64_t r = 0; r < rows; ++r) {
    uint16_t *hr = h + r * h_stride;
    cell_row(gates + r * g_stride, c + r * c_stride, hr, hidden);
    tail_row(tail, hr, hidden, r);
  }
  return 0;
#else
  (void)gates; (void)g_stride; (void)c; (void)c_stride; (void)h; (void)h_stride; (void)rows; (void)hidden;
  (void)tail;
  return -1;
#endif
}
