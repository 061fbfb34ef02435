// All-pairs Lennard-Jones forces and strain derivative for small periodic boxes, as an XLA FFI
// custom call on CPU (md/lj/native.py builds and registers it).
//
// The same arithmetic as md.lj.dense.all_pairs_force_and_strain (equal to float32 rounding: sums
// run in another order).  XLA's CPU code for that (N, N) broadcast materialises every
// intermediate and vectorises poorly; here one SIMD lane holds one system of the batch, so the
// loop over the N (N - 1) / 2 pairs is plain vector arithmetic.
//
// Inputs (float32, row-major, any leading batch dims B...):
//   position (B..., N, 3)  fractional coordinates in the unit cube
//   side     (B..., 3)     orthorhombic box sides, nm
//   sigma    (B...)        nm
//   epsilon  (B...)        kJ/mol
// Attributes: cutoff (float, nm); shifted (int32: 1 subtracts the pair energy at the cutoff).
// Outputs: force (B..., N, 3) kJ/mol/nm; strain (B...) = dU/d(eps) for r -> (1 + eps) r, kJ/mol;
// energy (B...) the pair energy U, kJ/mol.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

// Systems advanced together, one per SIMD lane: the pair loop then has no horizontal sums and
// Newton's third law costs no scatter (lanes are different systems).  16 float32 lanes fill an
// AVX-512 register; narrower machines split the loop into several vectors.
constexpr int kLanes = 16;

// One group of kLanes systems; `count` <= kLanes of them are real (the rest repeat the last).
void lane_group(const float* pos, const float* side, const float* sigma, const float* epsilon, float cutoff,
                bool shifted, int64_t n, int64_t first, int count, float* x, float* y, float* z, float* fx, float* fy,
                float* fz, float* force, float* strain, float* energy) {
  alignas(64) float lx[kLanes], ly[kLanes], lz[kLanes], s2[kLanes], e4[kLanes], st[kLanes], en[kLanes],
      shift[kLanes];
  const float rc2 = cutoff * cutoff;
  for (int l = 0; l < kLanes; ++l) {
    const int64_t b = first + (l < count ? l : count - 1);
    lx[l] = side[3 * b];
    ly[l] = side[3 * b + 1];
    lz[l] = side[3 * b + 2];
    s2[l] = sigma[b] * sigma[b];
    e4[l] = 4.0f * epsilon[b];
    const float qc = s2[l] / rc2, s6c = qc * qc * qc;
    shift[l] = shifted ? e4[l] * (s6c * s6c - s6c) : 0.0f;
    st[l] = 0.0f;
    en[l] = 0.0f;
    for (int64_t i = 0; i < n; ++i) {
      x[i * kLanes + l] = pos[(b * n + i) * 3];
      y[i * kLanes + l] = pos[(b * n + i) * 3 + 1];
      z[i * kLanes + l] = pos[(b * n + i) * 3 + 2];
    }
  }
  for (int64_t k = 0; k < n * kLanes; ++k) fx[k] = fy[k] = fz[k] = 0.0f;
  for (int64_t i = 0; i < n; ++i) {
    for (int64_t j = i + 1; j < n; ++j) {
      const int64_t a = i * kLanes, c = j * kLanes;
#pragma GCC ivdep
      for (int l = 0; l < kLanes; ++l) {
        float dx = x[c + l] - x[a + l], dy = y[c + l] - y[a + l], dz = z[c + l] - z[a + l];
        dx = (dx - std::nearbyint(dx)) * lx[l];
        dy = (dy - std::nearbyint(dy)) * ly[l];
        dz = (dz - std::nearbyint(dz)) * lz[l];
        const float r2 = dx * dx + dy * dy + dz * dz;
        const bool inside = r2 < rc2;
        const float inv = inside ? 1.0f / r2 : 0.0f;
        const float q = s2[l] * inv;
        const float s6 = q * q * q;
        const float du = e4[l] * (3.0f * s6 - 6.0f * s6 * s6) * inv;  // dU/d(r^2)
        const float g = 2.0f * du;  // F_i = sum_j 2 u' (r_j - r_i); F_j gets the opposite
        fx[a + l] += g * dx;
        fy[a + l] += g * dy;
        fz[a + l] += g * dz;
        fx[c + l] -= g * dx;
        fy[c + l] -= g * dy;
        fz[c + l] -= g * dz;
        st[l] += 2.0f * du * r2;  // dU/d(eps) = sum over pairs of 2 r^2 u'
        en[l] += inside ? e4[l] * (s6 * s6 - s6) - shift[l] : 0.0f;
      }
    }
  }
  for (int l = 0; l < count; ++l) {
    const int64_t b = first + l;
    for (int64_t i = 0; i < n; ++i) {
      force[(b * n + i) * 3] = fx[i * kLanes + l];
      force[(b * n + i) * 3 + 1] = fy[i * kLanes + l];
      force[(b * n + i) * 3 + 2] = fz[i * kLanes + l];
    }
    strain[b] = st[l];
    energy[b] = en[l];
  }
}

ffi::Error AllPairsImpl(ffi::Buffer<ffi::F32> position, ffi::Buffer<ffi::F32> side, ffi::Buffer<ffi::F32> sigma,
                        ffi::Buffer<ffi::F32> epsilon, float cutoff, int32_t shifted,
                        ffi::ResultBuffer<ffi::F32> force, ffi::ResultBuffer<ffi::F32> strain,
                        ffi::ResultBuffer<ffi::F32> energy) {
  auto dims = position.dimensions();
  if (dims.size() < 2 || dims[dims.size() - 1] != 3) {
    return ffi::Error::InvalidArgument("position must have shape (..., N, 3)");
  }
  const int64_t n = dims[dims.size() - 2];
  const int64_t batch = n > 0 ? static_cast<int64_t>(position.element_count()) / (3 * n) : 0;
  if (static_cast<int64_t>(side.element_count()) != 3 * batch ||
      static_cast<int64_t>(sigma.element_count()) != batch ||
      static_cast<int64_t>(epsilon.element_count()) != batch) {
    return ffi::Error::InvalidArgument("side (..., 3), sigma (...) and epsilon (...) must match position's batch");
  }
  std::vector<float> scratch(6 * static_cast<size_t>(n) * kLanes + 16);
  // 64-byte aligned start for the lane arrays.
  float* base = scratch.data();
  while (reinterpret_cast<uintptr_t>(base) % 64 != 0) ++base;
  float* x = base;
  float* y = x + n * kLanes;
  float* z = y + n * kLanes;
  float* fx = z + n * kLanes;
  float* fy = fx + n * kLanes;
  float* fz = fy + n * kLanes;
  for (int64_t first = 0; first < batch; first += kLanes) {
    const int count = static_cast<int>(batch - first < kLanes ? batch - first : kLanes);
    lane_group(position.typed_data(), side.typed_data(), sigma.typed_data(), epsilon.typed_data(), cutoff,
               shifted != 0, n, first, count, x, y, z, fx, fy, fz, force->typed_data(), strain->typed_data(),
               energy->typed_data());
  }
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(LjAllPairs, AllPairsImpl,
                              ffi::Ffi::Bind()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Attr<float>("cutoff")
                                  .Attr<int32_t>("shifted")
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>());
