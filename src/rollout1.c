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

// Batch-1 LSTM roll-out: the same function as physdyn_ros/learn/kernels.py's numpy_lstm_rollout (its layout,
// gate order and halvings; the sliding prior as learn/prior.py's prior_into, in double), in one call. At batch 1
// numpy's per-call cost exceeds the arithmetic; here the step loop runs without it. Results equal the numpy
// kernel's up to float32 rounding (another summation order, another tanh), which test_native_kernel.py bounds.
// Built by CMakeLists.txt into <prefix>/lib; learn/native.py loads it with ctypes.

#include <math.h>
#include <stdlib.h>
#include <string.h>

#if defined(__AVX2__) && defined(__FMA__)
#include <immintrin.h>
#define PHYSDYN_AVX2 1
#endif

#define SPEED_EPS 1e-6  // learn/prior.py's SPEED_EPS

// 1 when built with AVX2 and FMA (the loader then requires both CPU flags), else 0.
int physdyn_rollout1_simd(void) {
#ifdef PHYSDYN_AVX2
  return 1;
#else
  return 0;
#endif
}

// y = z W for a row vector z (k) and a row-major W (k x n) (the head's product).
static void gemv(const float *z, const float *w, int k, int n, float *y) {
  for (int j = 0; j < n; ++j) y[j] = 0.0f;
  for (int i = 0; i < k; ++i) {
    const float a = z[i], *r = w + (size_t)i * n;
    for (int j = 0; j < n; ++j) y[j] += a * r[j];
  }
}

// y = z W + b with W packed by native.pack: column panels of PANEL columns (the last one narrower), each panel's
// k rows contiguous, so that every panel streams through memory in order.
#define PANEL 64
static void gemv_packed(const float *z, const float *w, const float *b, int k, int n, float *y) {
  for (int j0 = 0; j0 < n; j0 += PANEL) {
    const int width = n - j0 < PANEL ? n - j0 : PANEL;
    const float *p = w + (size_t)j0 * k;
    int j = 0;
#ifdef PHYSDYN_AVX2
    if (width == PANEL) {  // 8 accumulators: enough independent FMAs to hide their latency
      __m256 a0 = _mm256_loadu_ps(b + j0), a1 = _mm256_loadu_ps(b + j0 + 8), a2 = _mm256_loadu_ps(b + j0 + 16);
      __m256 a3 = _mm256_loadu_ps(b + j0 + 24), a4 = _mm256_loadu_ps(b + j0 + 32);
      __m256 a5 = _mm256_loadu_ps(b + j0 + 40), a6 = _mm256_loadu_ps(b + j0 + 48);
      __m256 a7 = _mm256_loadu_ps(b + j0 + 56);
      for (int i = 0; i < k; ++i, p += PANEL) {
        __m256 s = _mm256_broadcast_ss(z + i);
        a0 = _mm256_fmadd_ps(s, _mm256_loadu_ps(p), a0);
        a1 = _mm256_fmadd_ps(s, _mm256_loadu_ps(p + 8), a1);
        a2 = _mm256_fmadd_ps(s, _mm256_loadu_ps(p + 16), a2);
        a3 = _mm256_fmadd_ps(s, _mm256_loadu_ps(p + 24), a3);
        a4 = _mm256_fmadd_ps(s, _mm256_loadu_ps(p + 32), a4);
        a5 = _mm256_fmadd_ps(s, _mm256_loadu_ps(p + 40), a5);
        a6 = _mm256_fmadd_ps(s, _mm256_loadu_ps(p + 48), a6);
        a7 = _mm256_fmadd_ps(s, _mm256_loadu_ps(p + 56), a7);
      }
      float *o = y + j0;
      _mm256_storeu_ps(o, a0);
      _mm256_storeu_ps(o + 8, a1);
      _mm256_storeu_ps(o + 16, a2);
      _mm256_storeu_ps(o + 24, a3);
      _mm256_storeu_ps(o + 32, a4);
      _mm256_storeu_ps(o + 40, a5);
      _mm256_storeu_ps(o + 48, a6);
      _mm256_storeu_ps(o + 56, a7);
      continue;
    }
#endif
    for (; j < width; ++j) y[j0 + j] = b[j0 + j];
    for (int i = 0; i < k; ++i, p += width) {
      const float a = z[i];
      for (j = 0; j < width; ++j) y[j0 + j] += a * p[j];
    }
  }
}

// tanh in float32 as a rational function (odd degree 13 over even degree 6, clamped where tanh rounds to +-1):
// a few ulp from the exact value, like numpy's own vectorised tanh, and free of libm's per-element call.
static inline float tanh_scalar(float x) {
  const float c = 7.90531110763549805f;
  float v = x > c ? c : (x < -c ? -c : x);
  if (fabsf(x) < 0.0004f) return x;
  float x2 = v * v;
  float p = -2.76076847742355e-16f;
  p = p * x2 + 2.00018790482477e-13f;
  p = p * x2 - 8.60467152213735e-11f;
  p = p * x2 + 5.12229709037114e-08f;
  p = p * x2 + 1.48572235717979e-05f;
  p = p * x2 + 6.37261928875436e-04f;
  p = p * x2 + 4.89352455891786e-03f;
  float q = 1.19825839466702e-06f;
  q = q * x2 + 1.18534705686654e-04f;
  q = q * x2 + 2.26843463243900e-03f;
  q = q * x2 + 4.89352518554385e-03f;
  return v * p / q;
}

static void tanh_inplace(float *a, int n) {
  int j = 0;
#ifdef PHYSDYN_AVX2
  const __m256 hi = _mm256_set1_ps(7.90531110763549805f), lo = _mm256_set1_ps(-7.90531110763549805f);
  const __m256 tiny = _mm256_set1_ps(0.0004f), sign = _mm256_set1_ps(-0.0f);
  for (; j + 8 <= n; j += 8) {
    __m256 x = _mm256_loadu_ps(a + j);
    __m256 v = _mm256_max_ps(_mm256_min_ps(x, hi), lo);
    __m256 x2 = _mm256_mul_ps(v, v);
    __m256 p = _mm256_set1_ps(-2.76076847742355e-16f);
    p = _mm256_fmadd_ps(p, x2, _mm256_set1_ps(2.00018790482477e-13f));
    p = _mm256_fmadd_ps(p, x2, _mm256_set1_ps(-8.60467152213735e-11f));
    p = _mm256_fmadd_ps(p, x2, _mm256_set1_ps(5.12229709037114e-08f));
    p = _mm256_fmadd_ps(p, x2, _mm256_set1_ps(1.48572235717979e-05f));
    p = _mm256_fmadd_ps(p, x2, _mm256_set1_ps(6.37261928875436e-04f));
    p = _mm256_fmadd_ps(p, x2, _mm256_set1_ps(4.89352455891786e-03f));
    __m256 q = _mm256_set1_ps(1.19825839466702e-06f);
    q = _mm256_fmadd_ps(q, x2, _mm256_set1_ps(1.18534705686654e-04f));
    q = _mm256_fmadd_ps(q, x2, _mm256_set1_ps(2.26843463243900e-03f));
    q = _mm256_fmadd_ps(q, x2, _mm256_set1_ps(4.89352518554385e-03f));
    __m256 t = _mm256_div_ps(_mm256_mul_ps(v, p), q);
    __m256 small = _mm256_cmp_ps(_mm256_andnot_ps(sign, x), tiny, _CMP_LT_OQ);
    _mm256_storeu_ps(a + j, _mm256_blendv_ps(t, x, small));
  }
#endif
  for (; j < n; ++j) a[j] = tanh_scalar(a[j]);
}

// learn/prior.py's prior_into: row[:12] and row[13:19] gain the sliding prior of input x (double arithmetic,
// each result rounded to float32 as numpy's float32 += Python float does).
static void prior_into(float *row, const float *x, const double *c) {
  double decel = c[0], spin = c[1], s0 = c[2], s1 = c[3], s5 = c[4], o0 = c[5], o1 = c[6], o5 = c[7], o6 = c[8];
  double o7 = c[9], o11 = c[10], g0 = c[11], g1 = c[12], g5 = c[13], dt = c[14], coupling = c[15];
  double vx = (double)x[0] * s0, vy = (double)x[1] * s1, wz = (double)x[5] * s5;
  double speed = sqrt(vx * vx + vy * vy + SPEED_EPS * SPEED_EPS);
  if (coupling != 0.0) {  // sliding_step's shared friction
    double lever_w = coupling * decel / (spin > 1e-9 ? spin : 1e-9) * fabs(wz);
    double norm = sqrt(speed * speed + lever_w * lever_w);
    double d = decel * speed / norm;
    spin = spin * lever_w / norm;
    decel = d;
  }
  double t = dt;
  if (decel > 0 && speed / decel <= dt) t = speed / decel;
  double dist = speed * t - 0.5 * decel * t * t;
  double nv = speed - decel * dt;
  if (!(nv >= 0.0)) nv = 0.0;
  double ux = vx / speed, uy = vy / speed;
  double p0 = (nv * ux - vx) * o0, p1 = (nv * uy - vy) * o1;
  row[0] += (float)p0;
  row[1] += (float)p1;
  row[6] += (float)(dist * ux * o6);
  row[7] += (float)(dist * uy * o7);
  row[13] += (float)(g0 * p0);
  row[14] += (float)(g1 * p1);
  if (wz != 0.0) {
    double w_abs = fabs(wz), sign = copysign(1.0, wz);
    double ts = dt;
    if (spin > 0 && w_abs / spin <= dt) ts = w_abs / spin;
    double left = w_abs - spin * dt;
    if (!(left >= 0.0)) left = 0.0;
    double p5 = (sign * left - wz) * o5;
    row[5] += (float)p5;
    row[11] += (float)(sign * (w_abs * ts - 0.5 * spin * ts * ts) * o11);
    row[18] += (float)(g5 * p5);
  }
}

// The roll-out. x0 (6), x_obs (observed x 6); w0 ((7 + hidden) x 4 hidden; its bias row 6 is not read) and
// bias0 (4 hidden: that row, the object's feature term), w[l] ((2 hidden + 1) x 4 hidden) for layers 1.., all
// packed; w_head ((6 + layers (hidden + 1)) x cols) row-major; prior: prior_constants' 16 numbers or NULL.
// out (steps x cols): per step the raw outputs, then the next input. Returns 0, or -1 when the sizes do not fit.
int physdyn_rollout1(const float *x0, const float *x_obs, int observed, const float *w0, const float *bias0,
                     const float *const *w, int layers, int hidden, const float *w_head, int cols, int steps,
                     const double *prior, float *out) {
  // the prior writes outputs 0-11 and the next input's components 13, 14, 18 (cols = 13 + 6)
  if (layers < 1 || hidden < 1 || cols < (prior != NULL ? 19 : 6) || steps < 0 || observed < 0) return -1;
  const int h = hidden, size = 6 + layers * (h + 1);
  float *z = calloc((size_t)size + (size_t)9 * h, sizeof(float));
  if (z == NULL) return -1;
  float *gates = z + size;  // tanh of (o, i, f, g), then the cell state c
  float *zeros = gates + 5 * h;  // the bias of layers 1.. is their row h of w
  float *cells = calloc((size_t)layers * h, sizeof(float));
  if (cells == NULL) {
    free(z);
    return -1;
  }
  memcpy(z, x0, 6 * sizeof(float));
  for (int l = 0; l < layers; ++l) z[6 + l * (h + 1)] = 1.0f;
  for (int t = 0; t < steps; ++t) {
    for (int l = 0; l < layers; ++l) {
      const int lo = 7 + l * (h + 1);
      float *c = cells + (size_t)l * h, *hs = z + lo;
      if (l == 0) {
        z[6] = 0.0f;  // row 6 of w0 is the per-object bias0, added instead
        gemv_packed(z, w0, bias0, 7 + h, 4 * h, gates);
        z[6] = 1.0f;
      } else {
        gemv_packed(z + lo - h - 1, w[l - 1], zeros, 2 * h + 1, 4 * h, gates);
      }
      tanh_inplace(gates, 4 * h);
      for (int j = 0; j < 3 * h; ++j) gates[j] += 1.0f;  // 2 sigmoid for o, i, f
      for (int j = 0; j < h; ++j) {
        float ig = gates[h + j] * gates[3 * h + j], fc = gates[2 * h + j] * c[j];  // 2 i tanh(g), 2 f c
        c[j] = 0.5f * ig + 0.5f * fc;
      }
      memcpy(gates + 4 * h, c, (size_t)h * sizeof(float));
      tanh_inplace(gates + 4 * h, h);
      for (int j = 0; j < h; ++j) hs[j] = gates[j] * gates[4 * h + j];  // 2 o tanh(c)
    }
    float *row = out + (size_t)t * cols;
    gemv(z, w_head, size, cols, row);
    if (prior != NULL) prior_into(row, z, prior);
    if (t < observed) memcpy(row + cols - 6, x_obs + (size_t)t * 6, 6 * sizeof(float));
    memcpy(z, row + cols - 6, 6 * sizeof(float));
  }
  free(cells);
  free(z);
  return 0;
}
