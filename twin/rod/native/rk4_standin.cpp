// A plain-C++ stand-in for the Eigen RK4 integrators the predictor is compared with
// (`twin bench peers`): the Rucker & Webster (2011) tendon-robot statics as Till's examples
// write them, with fixed-size 3x3 arithmetic in place of Eigen's, built at bench time.
//
// State (18): p (3), R (9, row-major), v (3), u (3). Each RK4 stage builds R&W's matrices
// A, B, G, H and vectors a, b over the tendons (eqs. 13-17) and solves the 6x6 system
//     [K_se + A, G; B, K_bt + H] [v'; u'] = [d; c]
// by Gaussian elimination with partial pivoting, as Eigen's partialPivLu does. The rod is
// uniform (v* = e3, u* = 0) under its own weight f_e (distributed, world frame); tendons run
// at r_i(s) = rho(s) (cos th, sin th, 0), rho linear from r0 to r1, th = alpha + omega s.
//
// Usage: rk4_standin STEPS REPEATS L KSE0 KSE1 KSE2 KBT0 KBT1 KBT2 FX FY FZ R00..R22 V0 V1 V2 U0 U1 U2
//                    NT (R0 R1 ALPHA OMEGA TAU) x NT
// Prints one line: CPU seconds per integration (CLOCK_PROCESS_CPUTIME_ID), then the tip position (m).
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <initializer_list>

namespace {

const int kMaxTendons = 16;

struct Rod {
    double L, kse[3], kbt[3], f[3], R0[9], v0[3], u0[3];
    int nt;
    double r0[kMaxTendons], r1[kMaxTendons], alpha[kMaxTendons], omega[kMaxTendons], tau[kMaxTendons];
};

inline void cross(const double* a, const double* b, double* out) {
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

// Solve the 6x6 system m x = rhs (both destroyed) by elimination with partial pivoting.
bool solve6(double m[6][6], double rhs[6], double x[6]) {
    for (int k = 0; k < 6; ++k) {
        int piv = k;
        for (int i = k + 1; i < 6; ++i)
            if (std::fabs(m[i][k]) > std::fabs(m[piv][k])) piv = i;
        if (m[piv][k] == 0.0) return false;
        if (piv != k) {
            for (int j = 0; j < 6; ++j) { double t = m[k][j]; m[k][j] = m[piv][j]; m[piv][j] = t; }
            double t = rhs[k]; rhs[k] = rhs[piv]; rhs[piv] = t;
        }
        for (int i = k + 1; i < 6; ++i) {
            double f = m[i][k] / m[k][k];
            for (int j = k; j < 6; ++j) m[i][j] -= f * m[k][j];
            rhs[i] -= f * rhs[k];
        }
    }
    for (int i = 5; i >= 0; --i) {
        double acc = rhs[i];
        for (int j = i + 1; j < 6; ++j) acc -= m[i][j] * x[j];
        x[i] = acc / m[i][i];
    }
    return true;
}

void deriv(const Rod& rod, double s, const double* y, double* dy) {
    const double* R = y + 3;
    const double* v = y + 12;
    const double* u = y + 15;
    double A[3][3] = {}, G[3][3] = {}, B[3][3] = {}, H[3][3] = {}, a[3] = {}, b[3] = {};
    for (int i = 0; i < rod.nt; ++i) {
        double rho = rod.r0[i] + (rod.r1[i] - rod.r0[i]) * s / rod.L, drho = (rod.r1[i] - rod.r0[i]) / rod.L;
        double w = rod.omega[i], th = rod.alpha[i] + w * s, c = std::cos(th), sn = std::sin(th);
        double r[3] = {rho * c, rho * sn, 0.0};
        double rs[3] = {drho * c - rho * w * sn, drho * sn + rho * w * c, 0.0};
        double rss[3] = {-2.0 * drho * w * sn - rho * w * w * c, 2.0 * drho * w * c - rho * w * w * sn, 0.0};
        double q[3];
        cross(u, r, q);
        for (int k = 0; k < 3; ++k) q[k] += rs[k] + v[k];
        double qn2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2], qn = std::sqrt(qn2);
        // A_i = -tau/|q|^3 q^2 (q^ the cross-product matrix) = tau/|q| (I - q q^T/|q|^2).
        double Ai[3][3];
        for (int j = 0; j < 3; ++j)
            for (int k = 0; k < 3; ++k)
                Ai[j][k] = rod.tau[i] / (qn2 * qn) * ((j == k ? qn2 : 0.0) - q[j] * q[k]);
        double rh[3][3] = {{0, -r[2], r[1]}, {r[2], 0, -r[0]}, {-r[1], r[0], 0}};
        double Gi[3][3], Bi[3][3], Hi[3][3];
        for (int j = 0; j < 3; ++j)
            for (int k = 0; k < 3; ++k) {
                Gi[j][k] = 0.0;
                Bi[j][k] = 0.0;
                for (int l = 0; l < 3; ++l) {
                    Gi[j][k] -= Ai[j][l] * rh[l][k];
                    Bi[j][k] += rh[j][l] * Ai[l][k];
                }
            }
        for (int j = 0; j < 3; ++j)
            for (int k = 0; k < 3; ++k) {
                Hi[j][k] = 0.0;
                for (int l = 0; l < 3; ++l) Hi[j][k] += rh[j][l] * Gi[l][k];
            }
        // a_i = A_i (u x q + u x r' + r'').
        double uq[3], urs[3], tmp[3], ai[3];
        cross(u, q, uq);
        cross(u, rs, urs);
        for (int k = 0; k < 3; ++k) tmp[k] = uq[k] + urs[k] + rss[k];
        for (int j = 0; j < 3; ++j) ai[j] = Ai[j][0] * tmp[0] + Ai[j][1] * tmp[1] + Ai[j][2] * tmp[2];
        double bi[3];
        cross(r, ai, bi);
        for (int j = 0; j < 3; ++j) {
            a[j] += ai[j];
            b[j] += bi[j];
            for (int k = 0; k < 3; ++k) {
                A[j][k] += Ai[j][k];
                G[j][k] += Gi[j][k];
                B[j][k] += Bi[j][k];
                H[j][k] += Hi[j][k];
            }
        }
    }
    // c = -u x K_bt u - v x K_se (v - e3) - R^T l - b;  d = -u x K_se (v - e3) - R^T f - a  (l = 0).
    double nb[3] = {rod.kse[0] * v[0], rod.kse[1] * v[1], rod.kse[2] * (v[2] - 1.0)};
    double mb[3] = {rod.kbt[0] * u[0], rod.kbt[1] * u[1], rod.kbt[2] * u[2]};
    double fb[3];
    for (int k = 0; k < 3; ++k) fb[k] = R[k] * rod.f[0] + R[3 + k] * rod.f[1] + R[6 + k] * rod.f[2];
    double umb[3], vnb[3], unb[3];
    cross(u, mb, umb);
    cross(v, nb, vnb);
    cross(u, nb, unb);
    double M[6][6], rhs[6], x[6];
    for (int j = 0; j < 3; ++j) {
        rhs[j] = -unb[j] - fb[j] - a[j];
        rhs[3 + j] = -umb[j] - vnb[j] - b[j];
        for (int k = 0; k < 3; ++k) {
            M[j][k] = A[j][k] + (j == k ? rod.kse[j] : 0.0);
            M[j][3 + k] = G[j][k];
            M[3 + j][k] = B[j][k];
            M[3 + j][3 + k] = H[j][k] + (j == k ? rod.kbt[j] : 0.0);
        }
    }
    solve6(M, rhs, x);
    // p' = R v, R' = R u^, v' and u' from the solve.
    for (int j = 0; j < 3; ++j) {
        dy[j] = R[3 * j] * v[0] + R[3 * j + 1] * v[1] + R[3 * j + 2] * v[2];
        const double* row = R + 3 * j;
        double* out = dy + 3 + 3 * j;
        out[0] = row[1] * u[2] - row[2] * u[1];
        out[1] = row[2] * u[0] - row[0] * u[2];
        out[2] = row[0] * u[1] - row[1] * u[0];
        dy[12 + j] = x[j];
        dy[15 + j] = x[3 + j];
    }
}

void integrate(const Rod& rod, int steps, double* y) {
    for (int k = 0; k < 3; ++k) y[k] = 0.0;
    for (int k = 0; k < 9; ++k) y[3 + k] = rod.R0[k];
    for (int k = 0; k < 3; ++k) { y[12 + k] = rod.v0[k]; y[15 + k] = rod.u0[k]; }
    double h = rod.L / steps, k1[18], k2[18], k3[18], k4[18], yt[18];
    for (int n = 0; n < steps; ++n) {
        double s = n * h;
        deriv(rod, s, y, k1);
        for (int i = 0; i < 18; ++i) yt[i] = y[i] + 0.5 * h * k1[i];
        deriv(rod, s + 0.5 * h, yt, k2);
        for (int i = 0; i < 18; ++i) yt[i] = y[i] + 0.5 * h * k2[i];
        deriv(rod, s + 0.5 * h, yt, k3);
        for (int i = 0; i < 18; ++i) yt[i] = y[i] + h * k3[i];
        deriv(rod, s + h, yt, k4);
        for (int i = 0; i < 18; ++i) y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
    }
}

double cpu_seconds() {
    timespec t;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

}  // namespace

int main(int argc, char** argv) {
    const int fixed = 3 + 1 + 3 + 3 + 3 + 9 + 3 + 3 + 1;
    if (argc < fixed + 1) {
        std::fprintf(stderr, "usage: see the header of rk4_standin.cpp\n");
        return 2;
    }
    int a = 1;
    int steps = std::atoi(argv[a++]);
    long repeats = std::atol(argv[a++]);
    Rod rod;
    rod.L = std::atof(argv[a++]);
    for (double* field : {rod.kse, rod.kbt, rod.f})
        for (int k = 0; k < 3; ++k) field[k] = std::atof(argv[a++]);
    for (int k = 0; k < 9; ++k) rod.R0[k] = std::atof(argv[a++]);
    for (int k = 0; k < 3; ++k) rod.v0[k] = std::atof(argv[a++]);
    for (int k = 0; k < 3; ++k) rod.u0[k] = std::atof(argv[a++]);
    rod.nt = std::atoi(argv[a++]);
    if (steps < 1 || repeats < 1 || rod.nt < 0 || rod.nt > kMaxTendons || argc != a + 5 * rod.nt) {
        std::fprintf(stderr, "rk4_standin: bad arguments\n");
        return 2;
    }
    for (int i = 0; i < rod.nt; ++i) {
        rod.r0[i] = std::atof(argv[a++]);
        rod.r1[i] = std::atof(argv[a++]);
        rod.alpha[i] = std::atof(argv[a++]);
        rod.omega[i] = std::atof(argv[a++]);
        rod.tau[i] = std::atof(argv[a++]);
    }
    double y[18], sink = 0.0, u00 = rod.u0[0];
    double start = cpu_seconds();
    for (long n = 0; n < repeats; ++n) {
        rod.u0[0] += 1e-300;  // a different input each time, so no integration can be hoisted
        integrate(rod, steps, y);
        sink += y[0];
    }
    double per = (cpu_seconds() - start) / repeats;
    rod.u0[0] = u00;
    integrate(rod, steps, y);
    std::printf("%.9e %.17g %.17g %.17g %s\n", per, y[0], y[1], y[2], sink == sink ? "" : "nan");
    return 0;
}
