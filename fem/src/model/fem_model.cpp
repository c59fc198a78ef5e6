#include "palp/fem/fem_model.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <sstream>
#include <string>

#include "index_cast.h"
#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/parallel.h"
#include "palp/fem/hex_element.h"

namespace palp::fem {

namespace {

/// One register of doubles per instruction set the kernel is compiled for: eight (AVX-512),
/// four (AVX2) or two (SSE2).
typedef double V8 __attribute__((vector_size(64)));
typedef double V4 __attribute__((vector_size(32)));
typedef double V2 __attribute__((vector_size(16)));

/// f_e += E_e Ke u_e for @p B consecutive cells of one x-row starting at dof @p base (cell t of
/// the batch at base + 3 t), with vectors @p V of @p W doubles. Ke u_e is 576 multiply-adds per
/// cell; doing B cells together loads each piece of a Ke column once for B FMAs (the loop is
/// bound by loads, not by arithmetic). The 24 rows go in passes of @p NV vectors, so a pass
/// holds B x NV accumulators (x 3 interleaved column groups when B = 1, to hide the FMA
/// latency). The shape is chosen per instruction set so that the accumulators, one column
/// vector and the B broadcasts of u fit the registers: AVX-512 B 4 x NV 3 in one pass (12 of
/// 32), AVX2 and SSE2 B 3 x NV 3 (9 of 16; two and four passes). One 24-row pass of eight-wide
/// vectors compiled for AVX2 needed 24 accumulator registers and spilled: a 13^3 stiffness
/// product took 1,050 us against 42 us on AVX-512; this shape takes 136 us on the same AMD
/// AVX2 machine (B 4 x NV 3: 185 us; B 4 x NV 2: 148 us).
template <class V, int W, int B, int NV>
[[gnu::always_inline]] inline void cellBatch(const double* __restrict ke,
                                             const double* __restrict e,
                                             const std::ptrdiff_t* chunk, std::ptrdiff_t base,
                                             const double* __restrict u,
                                             double* __restrict f) noexcept {
    constexpr int kRows = NV * W;  // rows of Ke per pass
    constexpr int kPasses = 24 / kRows;
    constexpr int kGroups = B >= 3 ? 1 : (B == 2 ? 2 : 3);  // divides 6
    constexpr std::size_t kB = B, kG = kGroups, kNV = NV;
    double fe[kB][24];
    for (int p = 0; p < kPasses; ++p) {
        V acc[kB][kG][kNV];
        for (int t = 0; t < B; ++t) {
            for (int g = 0; g < kGroups; ++g) {
                for (int v = 0; v < NV; ++v) acc[t][g][v] = V{};
            }
        }
#pragma GCC unroll 4
        for (int q = 0; q < 4; ++q) {
            const double* uq = u + base + chunk[q];
            // Opaque to the optimiser, so each pass broadcasts u again from memory instead of
            // keeping all 96 broadcasts of the batch on the stack across the passes.
            asm("" : "+r"(uq));
#pragma GCC unroll 6
            for (int r = 0; r < 6; r += kGroups) {
#pragma GCC unroll 4
                for (int g = 0; g < kGroups; ++g) {
                    const V* kc = reinterpret_cast<const V*>(ke + 24 * (6 * q + r + g) + kRows * p);
#pragma GCC unroll 6
                    for (int v = 0; v < NV; ++v) {
                        const V k = kc[v];
#pragma GCC unroll 4
                        for (int t = 0; t < B; ++t) acc[t][g][v] += k * uq[r + g + 3 * t];
                    }
                }
            }
        }
        for (int t = 0; t < B; ++t) {
            for (int v = 0; v < NV; ++v) {
                V sum = acc[t][0][v];
                for (int g = 1; g < kGroups; ++g) sum += acc[t][g][v];
                sum *= e[t];
                for (int r = 0; r < W; ++r) fe[t][kRows * p + W * v + r] = sum[r];
            }
        }
    }
    for (int t = 0; t < B; ++t) {
        const std::ptrdiff_t cellBase = base + 3 * t;
        for (int q = 0; q < 4; ++q) {
            for (int r = 0; r < 6; ++r) f[cellBase + chunk[q] + r] += fe[t][6 * q + r];
        }
    }
}

/// The hot loop: for every active cell of slabs [kBegin, kEnd), f_e += E_e Ke u_e. Cells go in
/// batches of B along x; a batch containing void cells (E = 0) adds exact zeros for them, and
/// a batch of only void cells is skipped.
template <class V, int W, int B, int NV>
[[gnu::always_inline]] inline void elementLoop(const double* __restrict ke,
                                               const double* __restrict cellE, int nx, int ny,
                                               int kBegin, int kEnd, const double* __restrict u,
                                               double* __restrict f) noexcept {
    const int cx = nx - 1;
    const int cy = ny - 1;
    const std::ptrdiff_t dy = 3 * static_cast<std::ptrdiff_t>(nx);
    const std::ptrdiff_t dz = 3 * static_cast<std::ptrdiff_t>(nx) * ny;
    const std::ptrdiff_t chunk[4] = {0, dy, dz, dy + dz};
    const double* __restrict kd = static_cast<const double*>(__builtin_assume_aligned(ke, 64));
    for (int k = kBegin; k < kEnd; ++k) {
        for (int j = 0; j < cy; ++j) {
            const double* rowE = cellE + static_cast<std::ptrdiff_t>(cx) * (j + cy * k);
            const std::ptrdiff_t rowBase = 3 * static_cast<std::ptrdiff_t>(nx) * (j + ny * k);
            int i = 0;
            for (; i + B <= cx; i += B) {
                if (std::all_of(rowE + i, rowE + i + B, [](double e) { return e == 0.0; }))
                    continue;
                cellBatch<V, W, B, NV>(kd, rowE + i, chunk, rowBase + 3 * i, u, f);
            }
            for (; i < cx; ++i) {
                if (rowE[i] == 0.0) continue;
                cellBatch<V, W, 1, NV>(kd, rowE + i, chunk, rowBase + 3 * i, u, f);
            }
        }
    }
}

/// The loop compiled for AVX-512, AVX2 and baseline x86-64, each with its own vector width, and
/// chosen at load time (GCC function multiversioning), so the library stays portable while the
/// fixed-size 24x24 product is vectorised. Sanitizer builds get the baseline only: the ifunc
/// resolver runs before the sanitizer runtime is up and crashes under TSan.
#define PALP_ELEMENT_KERNEL_ARGS                                                             \
    const double *__restrict ke, const double *__restrict cellE, int nx, int ny, int kBegin, \
        int kEnd, const double *__restrict u, double *__restrict f
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && \
    !defined(__SANITIZE_THREAD__) && !defined(__SANITIZE_ADDRESS__)
__attribute__((target("arch=x86-64-v4"))) void elementKernel(PALP_ELEMENT_KERNEL_ARGS) noexcept {
    elementLoop<V8, 8, 4, 3>(ke, cellE, nx, ny, kBegin, kEnd, u, f);
}
__attribute__((target("arch=x86-64-v3"))) void elementKernel(PALP_ELEMENT_KERNEL_ARGS) noexcept {
    elementLoop<V4, 4, 3, 3>(ke, cellE, nx, ny, kBegin, kEnd, u, f);
}
__attribute__((target("default"))) void elementKernel(PALP_ELEMENT_KERNEL_ARGS) noexcept {
    elementLoop<V2, 2, 3, 3>(ke, cellE, nx, ny, kBegin, kEnd, u, f);
}
#else
void elementKernel(PALP_ELEMENT_KERNEL_ARGS) noexcept {
    elementLoop<V2, 2, 3, 3>(ke, cellE, nx, ny, kBegin, kEnd, u, f);
}
#endif
#undef PALP_ELEMENT_KERNEL_ARGS

}  // namespace

FemModel::FemModel(HexMesh mesh, const ElasticMaterial& material)
    : mMesh(std::move(mesh)), mMaterial(material) {
    validate(material);
    if (mMesh.elementCount() == 0) {
        throw ValueError("FEM model mesh: expected at least one element, found an empty mesh");
    }
    const double h = mMesh.edge();
    const Eigen::Matrix<double, 24, 24> ke = hexStiffness(h, 1.0, material.poissonRatio);
    std::copy(ke.data(), ke.data() + 576, mUnitKe.begin());

    const double nodeMass = material.density * h * h * h / 8.0;
    mMass = Eigen::VectorXd::Zero(mMesh.dofCount());
    double maxE = 0.0;
    for (int c = 0; c < mMesh.cellCount(); ++c) {
        if (!mMesh.cellActive(c)) continue;
        const double e = mMesh.cellYoungs()[sz(c)];
        if (!bounds::kYoungsModulus.contains(e)) {
            requireWithin("FEM model mesh cellYoungs[" + std::to_string(c) + "]", e,
                          bounds::kYoungsModulus);
        }
        maxE = std::max(maxE, e);
        for (int n : mMesh.cellNodes(c)) {
            for (int d = 0; d < 3; ++d) mMass[3 * n + d] += nodeMass;
        }
    }
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 24, 24>> eig(ke,
                                                                           Eigen::EigenvaluesOnly);
    mOmegaMax = std::sqrt(maxE * eig.eigenvalues().maxCoeff() / nodeMass);
}

double FemModel::totalMass() const { return mMass.sum() / 3.0; }

void FemModel::addStiffnessTimesSlab(const double* u, double* f, int kBegin,
                                     int kEnd) const noexcept {
    elementKernel(mUnitKe.data(), mMesh.cellYoungs().data(), mMesh.nodeCounts()[0],
                  mMesh.nodeCounts()[1], kBegin, kEnd, u, f);
}

void FemModel::addStiffnessTimes(const double* u, double* f) const noexcept {
    addStiffnessTimesSlab(u, f, 0, mMesh.nodeCounts()[2] - 1);
}

void FemModel::stiffnessTimesParallel(const double* u, double* f) const {
    const int cz = mMesh.nodeCounts()[2] - 1;
    std::fill(f, f + mMesh.dofCount(), 0.0);
    for (int parity = 0; parity < 2; ++parity) {
        const int slabs = (cz - parity + 1) / 2;
        parallelFor(tbb::blocked_range<int>(0, slabs), [&](const tbb::blocked_range<int>& r) {
            for (int s = r.begin(); s != r.end(); ++s) {
                const int k = 2 * s + parity;
                addStiffnessTimesSlab(u, f, k, k + 1);
            }
        });
    }
}

double FemModel::criticalTimeStep() const {
    const double w = mOmegaMax;
    const double xi = 0.5 * (mMaterial.dampingAlpha / w + mMaterial.dampingBeta * w);
    // (sqrt(1 + xi^2) - xi) = 1 / (sqrt(1 + xi^2) + xi): the same step without the cancellation
    // that made it 0 for a large xi (beta 1e20 gave a zero substep).
    return 2.0 / (w * (std::sqrt(1.0 + xi * xi) + xi));
}

double FemModel::strainEnergy(const Eigen::VectorXd& u) const {
    Eigen::VectorXd f = Eigen::VectorXd::Zero(u.size());
    addStiffnessTimes(u.data(), f.data());
    return 0.5 * u.dot(f);
}

SparseMatrix FemModel::assembleStiffness() const {
    const auto& nc = mMesh.nodeCounts();
    const int nodes = mMesh.nodeCount();
    const int cx = nc[0] - 1;
    const int cy = nc[1] - 1;
    const int cz = nc[2] - 1;
    // Row structure: for each node, a sorted list of (neighbour, contributions from cells).
    // Entries are computed per node row by gathering from up to 8 adjacent active cells.
    std::vector<int> rowNnz(sz(nodes), 0);
    auto cellsOfNode = [&](int n, auto&& visit) {
        const auto ijk = mMesh.nodeCoords(n);
        for (int ck = ijk[2] - 1; ck <= ijk[2]; ++ck) {
            for (int cj = ijk[1] - 1; cj <= ijk[1]; ++cj) {
                for (int ci = ijk[0] - 1; ci <= ijk[0]; ++ci) {
                    if (ci < 0 || cj < 0 || ck < 0 || ci >= cx || cj >= cy || ck >= cz) continue;
                    const int c = mMesh.cell(ci, cj, ck);
                    if (!mMesh.cellActive(c)) continue;
                    // Local index of n inside cell c.
                    const int a = (ijk[0] - ci) + 2 * (ijk[1] - cj) + 4 * (ijk[2] - ck);
                    visit(c, a, ci, cj, ck);
                }
            }
        }
    };
    // Each task writes only its own nodes' rowNnz entries.
    parallelForEach(0, nodes, [&](int n) {
        // Mark which of the 27 neighbour offsets are coupled.
        bool used[27] = {};
        cellsOfNode(n, [&](int, int, int ci, int cj, int ck) {
            const auto ijk = mMesh.nodeCoords(n);
            for (int b = 0; b < 8; ++b) {
                const int di = ci + (b & 1) - ijk[0];
                const int dj = cj + ((b >> 1) & 1) - ijk[1];
                const int dk = ck + ((b >> 2) & 1) - ijk[2];
                used[(di + 1) + 3 * (dj + 1) + 9 * (dk + 1)] = true;
            }
        });
        int count = 0;
        for (bool b : used) count += b ? 1 : 0;
        rowNnz[sz(n)] = count;
    });
    const int dofs = 3 * nodes;
    SparseMatrix k(dofs, dofs);
    std::vector<int> outer(sz(dofs) + 1, 0);
    for (int n = 0; n < nodes; ++n) {
        for (int d = 0; d < 3; ++d)
            outer[sz(3 * n + d + 1)] = outer[sz(3 * n + d)] + 3 * rowNnz[sz(n)];
    }
    const int nnz = outer[sz(dofs)];
    k.resizeNonZeros(nnz);
    std::copy(outer.begin(), outer.end(), k.outerIndexPtr());
    int* inner = k.innerIndexPtr();
    double* values = k.valuePtr();
    const double* ke = mUnitKe.data();
    const std::vector<double>& youngs = mMesh.cellYoungs();
    // Each task writes only the entries of its own node's three rows (from outer[3n]).
    parallelForEach(0, nodes, [&](int n) {
        const auto ijk = mMesh.nodeCoords(n);
        double block[27][3][3] = {};
        bool used[27] = {};
        cellsOfNode(n, [&](int c, int a, int ci, int cj, int ck) {
            const double e = youngs[sz(c)];
            for (int b = 0; b < 8; ++b) {
                const int di = ci + (b & 1) - ijk[0];
                const int dj = cj + ((b >> 1) & 1) - ijk[1];
                const int dk = ck + ((b >> 2) & 1) - ijk[2];
                const int slot = (di + 1) + 3 * (dj + 1) + 9 * (dk + 1);
                used[slot] = true;
                for (int r = 0; r < 3; ++r) {
                    for (int s = 0; s < 3; ++s) {
                        // Column-major Ke: entry (row 3a+r, col 3b+s).
                        block[slot][r][s] += e * ke[24 * (3 * b + s) + 3 * a + r];
                    }
                }
            }
        });
        // Symmetric matrix: column 3n+d of K equals row 3n+d, so fill column storage by rows.
        for (int d = 0; d < 3; ++d) {
            int pos = outer[sz(3 * n + d)];
            for (int slot = 0; slot < 27; ++slot) {  // slot order is increasing node index
                if (!used[slot]) continue;
                const int di = slot % 3 - 1, dj = (slot / 3) % 3 - 1, dk = slot / 9 - 1;
                const int m = mMesh.node(ijk[0] + di, ijk[1] + dj, ijk[2] + dk);
                for (int s = 0; s < 3; ++s) {
                    inner[pos] = 3 * m + s;
                    values[pos] = block[slot][d][s];
                    ++pos;
                }
            }
        }
    });
    return k;
}

}  // namespace palp::fem
