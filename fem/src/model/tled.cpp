#include "palp/fem/tled.h"

#include <tbb/blocked_range.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>
#include <numbers>

#include "index_cast.h"
#include "model/tled_avx2.h"
#include "palp/base/error.h"
#include "palp/base/parallel.h"
#include "palp/base/simd.h"
#include "palp/base/validate.h"
#include "palp/fem/hex_element.h"

namespace palp::fem {

namespace {

/// Corner signs of the 8 local nodes (hex_mesh.h's order, x fastest).
constexpr double kSign[8][3] = {{-1, -1, -1}, {1, -1, -1}, {-1, 1, -1}, {1, 1, -1},
                                {-1, -1, 1},  {1, -1, 1},  {-1, 1, 1},  {1, 1, 1}};

/// Flanagan-Belytschko hourglass base vectors of the cube, one per mode (yz, xz, xy, xyz sign
/// products), normalised to unit length (entries +-1 / sqrt(8)). On a cube they are orthogonal
/// to the constant and linear nodal fields, so they see neither rigid nor affine motion.
struct HourglassVectors {
    double g[4][8];
    constexpr HourglassVectors() : g{} {
        const double s = 0.35355339059327373;  // 1 / sqrt(8)
        for (int a = 0; a < 8; ++a) {
            g[0][a] = s * kSign[a][1] * kSign[a][2];
            g[1][a] = s * kSign[a][0] * kSign[a][2];
            g[2][a] = s * kSign[a][0] * kSign[a][1];
            g[3][a] = s * kSign[a][0] * kSign[a][1] * kSign[a][2];
        }
    }
};
constexpr HourglassVectors kHourglass{};

/// Energy density and first Piola stress of the neo-Hookean law (mu, bulk) at F (row-major
/// 3x3): `P = mu J^(-2/3) F + (K (J - 1) - mu J^(-2/3) I1 / (3 J)) cof F`. Returns W.
[[gnu::always_inline]] inline double piola(const double (&f)[3][3], double mu, double bulk,
                                           double (&p)[3][3]) noexcept {
    double c[3][3];
    c[0][0] = f[1][1] * f[2][2] - f[1][2] * f[2][1];
    c[0][1] = f[1][2] * f[2][0] - f[1][0] * f[2][2];
    c[0][2] = f[1][0] * f[2][1] - f[1][1] * f[2][0];
    c[1][0] = f[0][2] * f[2][1] - f[0][1] * f[2][2];
    c[1][1] = f[0][0] * f[2][2] - f[0][2] * f[2][0];
    c[1][2] = f[0][1] * f[2][0] - f[0][0] * f[2][1];
    c[2][0] = f[0][1] * f[1][2] - f[0][2] * f[1][1];
    c[2][1] = f[0][2] * f[1][0] - f[0][0] * f[1][2];
    c[2][2] = f[0][0] * f[1][1] - f[0][1] * f[1][0];
    const double j = f[0][0] * c[0][0] + f[0][1] * c[0][1] + f[0][2] * c[0][2];
    double i1 = 0.0;
    for (int r = 0; r < 3; ++r) {
        for (int s = 0; s < 3; ++s) i1 += f[r][s] * f[r][s];
    }
    const double j23 = 1.0 / std::cbrt(j * j);  // J^(-2/3)
    const double a = mu * j23;
    const double b = bulk * (j - 1.0) - a * i1 / (3.0 * j);
    for (int r = 0; r < 3; ++r) {
        for (int s = 0; s < 3; ++s) p[r][s] = a * f[r][s] + b * c[r][s];
    }
    return 0.5 * mu * (j23 * i1 - 3.0) + 0.5 * bulk * (j - 1.0) * (j - 1.0);
}

/// Local dof offset of node a of a cell whose node 0 is at dof 0, for lattice rows of
/// @p dy dofs and planes of @p dz dofs.
struct NodeOffsets {
    std::ptrdiff_t o[8];
    NodeOffsets(std::ptrdiff_t dy, std::ptrdiff_t dz)
        : o{0, 3, dy, dy + 3, dz, dz + 3, dy + dz, dy + dz + 3} {}
    /// The offsets of @p mesh's lattice.
    static NodeOffsets of(const HexMesh& mesh) {
        const std::ptrdiff_t dy = 3 * static_cast<std::ptrdiff_t>(mesh.nodeCounts()[0]);
        return {dy, dy * mesh.nodeCounts()[1]};
    }
};

/// Largest and smallest eigenvalue of the symmetric 3x3 @p m (closed form, Smith 1961).
void symmetricExtremes(const double (&m)[3][3], double& lo, double& hi) noexcept {
    const double p1 = m[0][1] * m[0][1] + m[0][2] * m[0][2] + m[1][2] * m[1][2];
    const double q = (m[0][0] + m[1][1] + m[2][2]) / 3.0;
    const double d0 = m[0][0] - q, d1 = m[1][1] - q, d2 = m[2][2] - q;
    const double p2 = d0 * d0 + d1 * d1 + d2 * d2 + 2.0 * p1;
    if (p2 <= 1e-30 * q * q) {
        lo = hi = q;
        return;
    }
    const double p = std::sqrt(p2 / 6.0);
    const double b00 = d0 / p, b11 = d1 / p, b22 = d2 / p;
    const double b01 = m[0][1] / p, b02 = m[0][2] / p, b12 = m[1][2] / p;
    const double detB = b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) +
                        b02 * (b01 * b12 - b11 * b02);
    const double r = std::clamp(0.5 * detB, -1.0, 1.0);
    const double phi = std::acos(r) / 3.0;
    hi = q + 2.0 * p * std::cos(phi);
    lo = q + 2.0 * p * std::cos(phi + 2.0 * std::numbers::pi / 3.0);
}

/// Upper bound of the neo-Hookean acoustic tensor's largest eigenvalue at F (the second
/// derivative of W along F + t m N^T over unit m, N): with a = N . F^-1 m (|a| <= 1 / s_min)
/// and |m . F N| <= s_max it is at most
/// `mu / 2 J^(-2/3) (10/9 I1 a^2 + 8/3 |a| s_max + 2) + K J^2 a^2`.
double acousticBound(const double (&f)[3][3], double mu, double bulk) noexcept {
    double cg[3][3];
    for (int r = 0; r < 3; ++r) {
        for (int s = 0; s < 3; ++s)
            cg[r][s] = f[0][r] * f[0][s] + f[1][r] * f[1][s] + f[2][r] * f[2][s];
    }
    double lo = 0.0, hi = 0.0;
    symmetricExtremes(cg, lo, hi);
    const double j = f[0][0] * (f[1][1] * f[2][2] - f[1][2] * f[2][1]) -
                     f[0][1] * (f[1][0] * f[2][2] - f[1][2] * f[2][0]) +
                     f[0][2] * (f[1][0] * f[2][1] - f[1][1] * f[2][0]);
    if (!(lo > 0.0) || !(j > 0.0)) return std::numeric_limits<double>::infinity();
    const double i1 = cg[0][0] + cg[1][1] + cg[2][2];
    const double a2 = 1.0 / lo;
    return 0.5 * mu / std::cbrt(j * j) *
               (10.0 / 9.0 * i1 * a2 + 8.0 / 3.0 * std::sqrt(hi * a2) + 2.0) +
           bulk * j * j * a2;
}

/// The cell loop shared by the force, energy and frequency passes: calls
/// visit(E, dofOffset of node 0) for each active cell of slabs [kBegin, kEnd).
template <class Visit>
[[gnu::always_inline]] inline void forCells(const HexMesh& mesh, int kBegin, int kEnd,
                                            Visit&& visit) noexcept {
    const auto& nc = mesh.nodeCounts();
    const int cx = nc[0] - 1, cy = nc[1] - 1;
    const double* cellE = mesh.cellYoungs().data();
    for (int k = kBegin; k < kEnd; ++k) {
        for (int j = 0; j < cy; ++j) {
            const double* rowE = cellE + static_cast<std::ptrdiff_t>(cx) * (j + cy * k);
            const std::ptrdiff_t rowBase = 3 * static_cast<std::ptrdiff_t>(nc[0]) * (j + nc[1] * k);
            for (int i = 0; i < cx; ++i) {
                if (rowE[i] == 0.0) continue;
                visit(rowE[i], rowBase + 3 * i);
            }
        }
    }
}

/// F = I + (sum_a u_a grad_a^T) / h at one point, grad_a = h dN_a/dX there (dimensionless).
[[gnu::always_inline]] inline void deformationGradient(const double* __restrict u,
                                                       const NodeOffsets& off,
                                                       const double (*grad)[3], double invH,
                                                       double (&f)[3][3]) noexcept {
    double d[3][3] = {};
    for (int a = 0; a < 8; ++a) {
        const double* ua = u + off.o[a];
        for (int i = 0; i < 3; ++i) {
            for (int jj = 0; jj < 3; ++jj) d[i][jj] += ua[i] * grad[a][jj];
        }
    }
    for (int i = 0; i < 3; ++i) {
        for (int jj = 0; jj < 3; ++jj) f[i][jj] = (i == jj ? 1.0 : 0.0) + d[i][jj] * invH;
    }
}

/// The centre gradients h dN_a/dX = s_a / 4.
struct CentreGradients {
    double g[8][3];
    constexpr CentreGradients() : g{} {
        for (int a = 0; a < 8; ++a) {
            for (int jj = 0; jj < 3; ++jj) g[a][jj] = 0.25 * kSign[a][jj];
        }
    }
};
constexpr CentreGradients kCentre{};

/// acousticBound() of the undeformed state.
inline double restAcousticBound(const NeoHookean& unitLaw) noexcept {
    const double identity[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    return acousticBound(identity, unitLaw.mu, unitLaw.bulk);
}

/// How much stiffer than at rest the cell at @p ue (@p relE: its modulus over the largest) is:
/// the neo-Hookean acoustic bound at its centre over the rest one (@p rest), times @p relE.
/// Infinite for a NaN or an inverted cell (the step is then refused or capped).
inline double cellStiffening(const double* ue, const NodeOffsets& off, double invH, double relE,
                             const NeoHookean& unitLaw, double rest) noexcept {
    double fm[3][3];
    deformationGradient(ue, off, kCentre.g, invH, fm);
    const double r = acousticBound(fm, unitLaw.mu, unitLaw.bulk) / rest;
    return std::isnan(r) ? std::numeric_limits<double>::infinity() : relE * r;
}

/// The one-point element's forces of one cell of modulus @p e (law @p mu, @p bulk) added to
/// @p fe, @p ue and @p fe at the cell's node 0: F at the centre, `h^2 / 4 P s_a` per node plus
/// the hourglass springs @p kHg (for E = 1) on the four modes.
inline void onePointCell(const double* __restrict ue, double* __restrict fe, const NodeOffsets& off,
                         double invH, double area, double kHg, double mu, double bulk,
                         double e) noexcept {
    double fm[3][3], p[3][3];
    deformationGradient(ue, off, kCentre.g, invH, fm);
    piola(fm, mu, bulk, p);
    // Hourglass amplitudes q = G^T u per mode and component.
    double q[4][3] = {};
    for (int a = 0; a < 8; ++a) {
        const double* ua = ue + off.o[a];
        for (int al = 0; al < 4; ++al) {
            for (int i = 0; i < 3; ++i) q[al][i] += kHourglass.g[al][a] * ua[i];
        }
    }
    const double ke = e * kHg;
    for (int a = 0; a < 8; ++a) {
        double* fa = fe + off.o[a];
        for (int i = 0; i < 3; ++i) {
            double v = 0.0;
            for (int jj = 0; jj < 3; ++jj) v += p[i][jj] * kSign[a][jj];
            double hg = 0.0;
            for (int al = 0; al < 4; ++al) hg += kHourglass.g[al][a] * q[al][i];
            fa[i] += area * v + ke * hg;
        }
    }
}

/// The 2x2x2 element's forces of one cell (as onePointCell(); @p grad the Gauss points'
/// gradients, @p w the Gauss weight times 1 / h).
inline void gaussCell(const double* __restrict ue, double* __restrict fe, const NodeOffsets& off,
                      double invH, double w, const double (*grad)[8][3], double mu,
                      double bulk) noexcept {
    double acc[8][3] = {};
    for (int gp = 0; gp < 8; ++gp) {
        double fm[3][3], p[3][3];
        deformationGradient(ue, off, grad[gp], invH, fm);
        piola(fm, mu, bulk, p);
        for (int a = 0; a < 8; ++a) {
            for (int i = 0; i < 3; ++i) {
                acc[a][i] +=
                    p[i][0] * grad[gp][a][0] + p[i][1] * grad[gp][a][1] + p[i][2] * grad[gp][a][2];
            }
        }
    }
    for (int a = 0; a < 8; ++a) {
        double* fa = fe + off.o[a];
        for (int i = 0; i < 3; ++i) fa[i] += w * acc[a][i];
    }
}

}  // namespace

NeoHookean NeoHookean::fromYoungs(double e, double nu) noexcept {
    return {e / (2.0 * (1.0 + nu)), e / (3.0 * (1.0 - 2.0 * nu))};
}

double NeoHookean::energy(const Eigen::Matrix3d& fm) const noexcept {
    double f[3][3], p[3][3];
    for (int r = 0; r < 3; ++r) {
        for (int s = 0; s < 3; ++s) f[r][s] = fm(r, s);
    }
    return piola(f, mu, bulk, p);
}

Eigen::Matrix3d NeoHookean::firstPiola(const Eigen::Matrix3d& fm) const noexcept {
    double f[3][3], p[3][3];
    for (int r = 0; r < 3; ++r) {
        for (int s = 0; s < 3; ++s) f[r][s] = fm(r, s);
    }
    piola(f, mu, bulk, p);
    Eigen::Matrix3d out;
    for (int r = 0; r < 3; ++r) {
        for (int s = 0; s < 3; ++s) out(r, s) = p[r][s];
    }
    return out;
}

Eigen::Matrix3d NeoHookean::secondPiola(const Eigen::Matrix3d& f) const noexcept {
    const Eigen::Matrix3d c = f.transpose() * f;
    const Eigen::Matrix3d cInv = c.inverse();
    const double j = f.determinant();
    const double j23 = 1.0 / std::cbrt(j * j);
    return mu * j23 * (Eigen::Matrix3d::Identity() - c.trace() / 3.0 * cInv) +
           bulk * j * (j - 1.0) * cInv;
}

TledForces::TledForces(const FemModel& model, const TledOptions& options)
    : mModel(model), mOptions(options) {
    requireInRange("TLED hourglassKappa", options.hourglassKappa, 0.0, 1.0);
#ifdef PALP_TLED_AVX2
    mAvx2 = palp::avx2FmaEnabled();
#endif
    const ElasticMaterial& m = model.material();
    mUnitLaw = NeoHookean::fromYoungs(1.0, m.poissonRatio);
    const double g = 1.0 / std::sqrt(3.0);
    for (int p = 0; p < 8; ++p) {
        const double xi[3] = {(p & 1) ? g : -g, (p & 2) ? g : -g, (p & 4) ? g : -g};
        for (int a = 0; a < 8; ++a) {
            for (int jj = 0; jj < 3; ++jj) {
                // h dN_a/dX_J = (2 / 8) s_J prod_{K != J} (1 + s_K xi_K).
                double v = 0.25 * kSign[a][jj];
                for (int kk = 0; kk < 3; ++kk) {
                    if (kk != jj) v *= 1.0 + kSign[a][kk] * xi[kk];
                }
                mGaussGrad[p][a][jj] = v;
            }
        }
    }
    const HexMesh& mesh = model.mesh();
    for (int c = 0; c < mesh.cellCount(); ++c) {
        if (mesh.cellActive(c)) mCellEMax = std::max(mCellEMax, mesh.cellYoungs()[sz(c)]);
    }
    if (options.integration == TledIntegration::gauss2x2x2) {
        mOmegaRest = model.maxFrequencyBound();
        return;
    }
    // The undeformed one-point element's stiffness for E = 1: V B0^T C B0 plus the hourglass
    // springs; its largest eigenvalue over the node mass gives the rest frequency bound.
    const double h = mesh.edge();
    const Eigen::Matrix<double, 6, 24> b0 = hexStrainDisplacement(h, 0.0, 0.0, 0.0);
    Eigen::Matrix<double, 24, 24> ke =
        h * h * h * (b0.transpose() * elasticityMatrix(1.0, m.poissonRatio) * b0);
    const double kHg = hourglassStiffness(h);
    for (int al = 0; al < 4; ++al) {
        for (int a = 0; a < 8; ++a) {
            for (int b = 0; b < 8; ++b) {
                for (int i = 0; i < 3; ++i)
                    ke(3 * a + i, 3 * b + i) += kHg * kHourglass.g[al][a] * kHourglass.g[al][b];
            }
        }
    }
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 24, 24>> eig(
        0.5 * (ke + ke.transpose()), Eigen::EigenvaluesOnly);
    const double nodeMass = m.density * h * h * h / 8.0;
    mOmegaRest = std::sqrt(mCellEMax * eig.eigenvalues().maxCoeff() / nodeMass);
}

double TledForces::hourglassStiffness(double edge) const noexcept {
    return mOptions.hourglassKappa * (mUnitLaw.bulk + 4.0 / 3.0 * mUnitLaw.mu) * edge;
}

void TledForces::addInternalForcesSlab(const double* __restrict u, double* __restrict f, int kBegin,
                                       int kEnd) const noexcept {
    const HexMesh& mesh = mModel.mesh();
    const double h = mesh.edge(), invH = 1.0 / h;
    const NodeOffsets off = NodeOffsets::of(mesh);
    const double mu1 = mUnitLaw.mu, k1 = mUnitLaw.bulk;
    if (mOptions.integration == TledIntegration::onePointHourglass) {
        const double area = 0.25 * h * h;  // V |dN/dX| = h^3 / (4 h)
        const double kHg = hourglassStiffness(h);
        const auto cell = [&](double e, std::ptrdiff_t base) {
            onePointCell(u + base, f + base, off, invH, area, kHg, e * mu1, e * k1, e);
        };
#ifdef PALP_TLED_AVX2
        if (mAvx2) {
            // Four cells of a row at a time, the row's last cx % 4 cells one by one.
            const auto& nc = mesh.nodeCounts();
            const int cx = nc[0] - 1, cy = nc[1] - 1, groups = cx / 4;
            const double* cellE = mesh.cellYoungs().data();
            for (int k = kBegin; k < kEnd; ++k) {
                for (int j = 0; j < cy; ++j) {
                    const double* rowE = cellE + static_cast<std::ptrdiff_t>(cx) * (j + cy * k);
                    const std::ptrdiff_t rowBase =
                        3 * static_cast<std::ptrdiff_t>(nc[0]) * (j + nc[1] * k);
                    detail::onePointRowAvx2(u + rowBase, f + rowBase, rowE, groups, off.o,
                                            {0.25 * invH, area, mu1, k1, kHg / 8.0});
                    for (int i = 4 * groups; i < cx; ++i) {
                        if (rowE[i] != 0.0) cell(rowE[i], rowBase + 3 * i);
                    }
                }
            }
            return;
        }
#endif
        forCells(mesh, kBegin, kEnd, cell);
        return;
    }
    const double w = 0.125 * h * h;  // (h^3 / 8) / h: Gauss weight times dN/dX's 1 / h
    forCells(mesh, kBegin, kEnd, [&](double e, std::ptrdiff_t base) {
        gaussCell(u + base, f + base, off, invH, w, mGaussGrad, e * mu1, e * k1);
    });
}

void TledForces::addCellForces(const double* __restrict u, double* __restrict f,
                               std::span<const std::array<int, 8>> cellDofs,
                               std::span<const double> cellE) const noexcept {
    const HexMesh& mesh = mModel.mesh();
    const double h = mesh.edge(), invH = 1.0 / h;
    const NodeOffsets off = NodeOffsets::of(mesh);
    const double mu1 = mUnitLaw.mu, k1 = mUnitLaw.bulk;
    const std::size_t n = std::min(cellDofs.size(), cellE.size());
    if (mOptions.integration == TledIntegration::gauss2x2x2) {
        const double w = 0.125 * h * h;
        for (std::size_t c = 0; c < n; ++c) {
            const double e = cellE[c];
            if (e == 0.0) continue;
            const std::ptrdiff_t base = cellDofs[c][0];
            gaussCell(u + base, f + base, off, invH, w, mGaussGrad, e * mu1, e * k1);
        }
        return;
    }
    const double area = 0.25 * h * h, kHg = hourglassStiffness(h);
#ifdef PALP_TLED_AVX2
    if (mAvx2) {
        // Four cells one after the other in a lattice row (node 0 three dofs apart: a row's end
        // jumps by more) in one row group; the other cells four at a time from anywhere, the
        // last group padded with modulus 0.
        const detail::OnePointConstants k{0.25 * invH, area, mu1, k1, kHg / 8.0};
        std::ptrdiff_t bases[4];
        double moduli[4];
        int pending = 0;
        for (std::size_t c = 0; c < n;) {
            const std::ptrdiff_t base = cellDofs[c][0];
            if (c + 4 <= n && cellDofs[c + 1][0] == base + 3 && cellDofs[c + 2][0] == base + 6 &&
                cellDofs[c + 3][0] == base + 9) {
                detail::onePointRowAvx2(u + base, f + base, cellE.data() + c, 1, off.o, k);
                c += 4;
                continue;
            }
            if (cellE[c] != 0.0) {
                bases[pending] = base;
                moduli[pending] = cellE[c];
                if (++pending == 4) {
                    detail::onePointCellsAvx2(u, f, bases, moduli, off.o, k);
                    pending = 0;
                }
            }
            ++c;
        }
        if (pending > 0) {
            for (int l = pending; l < 4; ++l) {
                bases[l] = bases[0];
                moduli[l] = 0.0;
            }
            detail::onePointCellsAvx2(u, f, bases, moduli, off.o, k);
        }
        return;
    }
#endif
    for (std::size_t c = 0; c < n; ++c) {
        const std::ptrdiff_t base = cellDofs[c][0];
        const double e = cellE[c];
        if (e != 0.0) onePointCell(u + base, f + base, off, invH, area, kHg, e * mu1, e * k1, e);
    }
}

void TledForces::addInternalForces(const double* u, double* f) const noexcept {
    addInternalForcesSlab(u, f, 0, mModel.mesh().nodeCounts()[2] - 1);
}

void TledForces::internalForcesParallel(const double* u, double* f) const {
    const int cz = mModel.mesh().nodeCounts()[2] - 1;
    std::fill(f, f + mModel.dofCount(), 0.0);
    for (int parity = 0; parity < 2; ++parity) {
        const int slabs = (cz - parity + 1) / 2;
        parallelFor(tbb::blocked_range<int>(0, slabs), [&](const tbb::blocked_range<int>& r) {
            for (int s = r.begin(); s != r.end(); ++s) {
                const int k = 2 * s + parity;
                addInternalForcesSlab(u, f, k, k + 1);
            }
        });
    }
}

double TledForces::strainEnergy(const double* u) const noexcept {
    const HexMesh& mesh = mModel.mesh();
    const double h = mesh.edge(), invH = 1.0 / h, volume = h * h * h;
    const NodeOffsets off = NodeOffsets::of(mesh);
    const bool onePoint = mOptions.integration == TledIntegration::onePointHourglass;
    const double kHg = hourglassStiffness(h);
    double total = 0.0;
    forCells(mesh, 0, mesh.nodeCounts()[2] - 1, [&](double e, std::ptrdiff_t base) {
        const double* ue = u + base;
        double fm[3][3], p[3][3];
        if (onePoint) {
            deformationGradient(ue, off, kCentre.g, invH, fm);
            total += volume * piola(fm, e * mUnitLaw.mu, e * mUnitLaw.bulk, p);
            for (int al = 0; al < 4; ++al) {
                for (int i = 0; i < 3; ++i) {
                    double q = 0.0;
                    for (int a = 0; a < 8; ++a) q += kHourglass.g[al][a] * ue[off.o[a] + i];
                    total += 0.5 * e * kHg * q * q;
                }
            }
            return;
        }
        for (int gp = 0; gp < 8; ++gp) {
            deformationGradient(ue, off, mGaussGrad[gp], invH, fm);
            total += 0.125 * volume * piola(fm, e * mUnitLaw.mu, e * mUnitLaw.bulk, p);
        }
    });
    return total;
}

double TledForces::frequencyBound(const double* u) const noexcept {
    const HexMesh& mesh = mModel.mesh();
    const double invH = 1.0 / mesh.edge();
    const NodeOffsets off = NodeOffsets::of(mesh);
    const double rest = restAcousticBound(mUnitLaw);
    double worst = 0.0;
    forCells(mesh, 0, mesh.nodeCounts()[2] - 1, [&](double e, std::ptrdiff_t base) {
        worst = std::max(worst, cellStiffening(u + base, off, invH, e / mCellEMax, mUnitLaw, rest));
    });
    return boundFromStiffening(worst);
}

double TledForces::frequencyBoundCells(const double* u,
                                       std::span<const std::array<int, 8>> cellDofs,
                                       std::span<const double> cellE) const noexcept {
    const HexMesh& mesh = mModel.mesh();
    const double invH = 1.0 / mesh.edge();
    const NodeOffsets off = NodeOffsets::of(mesh);
    const double rest = restAcousticBound(mUnitLaw);
    double worst = 0.0;
    const std::size_t n = std::min(cellDofs.size(), cellE.size());
    for (std::size_t c = 0; c < n; ++c) {
        if (cellE[c] != 0.0)
            worst = std::max(worst, cellStiffening(u + cellDofs[c][0], off, invH,
                                                   cellE[c] / mCellEMax, mUnitLaw, rest));
    }
    return boundFromStiffening(worst);
}

double TledForces::boundFromStiffening(double worst) const noexcept {
    // Below the rest state (tension) the bound is kept at the rest value: stiffness lost to
    // stretching is not counted on.
    return mOmegaRest * std::sqrt(std::max(1.0, worst));
}

double TledForces::criticalTimeStep(double omega, double extraOmega2) const noexcept {
    const double w = std::sqrt(omega * omega + std::max(0.0, extraOmega2));
    const ElasticMaterial& m = mModel.material();
    const double xi = 0.5 * (m.dampingAlpha / w + m.dampingBeta * w);
    return 2.0 / (w * (std::sqrt(1.0 + xi * xi) + xi));
}

}  // namespace palp::fem
