r"""System identification: a rattleback's centre-of-mass height and inertia misalignment from noisy attitude samples.

The rattleback of Kane & Levinson (1982) as a PyDy user writes it (``sympy.physics.mechanics``,
``KanesMethod``, yaw ``q1``, roll ``q2``, pitch ``q3``, the contact point of zero velocity), with
two constants left as sympy symbols to be found from measurements:

* ``h``, the height of the centre of mass above the centre of the ellipsoid's bottom
  (``r_GP = ... + h R.z``), and
* ``delta``, the inertia misalignment: the principal axes of the body's inertia are its
  geometric axes (those of the ellipsoid) turned by ``delta`` about ``R.z``,

  .. math:: I = \begin{pmatrix} I_1 \cos^2\delta + I_2 \sin^2\delta & (I_2 - I_1)\sin\delta\cos\delta & 0 \\
                \cdot & I_1 \sin^2\delta + I_2 \cos^2\delta & 0 \\ 0 & 0 & C \end{pmatrix},

  with ``I_1, I_2`` the principal moments of Kane & Levinson's ``A = 2e-4, B = 1.6e-3,
  D = 2e-5`` (so ``delta = atan2(2D, B - A) / 2 = 0.01428`` rad, 0.82 degrees, is true).

**The measurements** are synthetic but honest: a run of liefi at the true constants from a known
launch (tilt 0.5 degrees in roll and pitch, spin 5 rad/s), its attitude ``(q1, q2, q3)`` sampled
every ``sample`` seconds over ``t_final`` and perturbed by Gaussian noise of ``sigma`` radians
(seeded).  The fit starts from another guess (``h = 0.012``, ``delta = 0.02``: 20 and 40 % off)
and knows neither constant.  The least-squares cost of a few seconds of a rattleback has other
minima: from ``h = 0.015, delta = 0.03`` the fit lands in one (residual RMS 3.9 degrees).

**The fit** is ``scipy.optimize.least_squares`` on the residuals
``r = (q(t_i; theta) - q_i) / sigma`` with ``jac=`` liefi's forward sensitivities: the
tangents of the run (:func:`liefi.integrator.sensitivity.tangents`) along two directions
of ``(y0, theta)`` -- the constant ``e_j`` and the start's own change ``d z0 / d theta_j``
(liefi's state ``z0 = (q, x_P, y_P, p)`` carries momenta, ``p = g(q; theta) qdot``, so the
same launch ``(q0, u0)`` is another ``z0`` at other constants; this derivative of an algebraic
map is the 8th-order central difference, exact to ~1e-13).  Each Jacobian is exact to rounding
for the numbers the run returned.

**The uncertainty.**  With ``J`` the Jacobian of ``q(t_i; theta)`` at the optimum and ``s^2 =
|q - q_data|^2 / (m - 2)`` the residual variance (``m`` residuals), the covariance of the
estimate is ``s^2 (J^T J)^{-1}``; each parameter's standard error ``sigma_j`` is the root of its
diagonal, and the recovered values are within the noise's confidence interval when
``|theta_j - theta_j^true| <= 2 sigma_j`` (95 %).

**Against finite differences.**  The same fit with ``least_squares``' own ``jac="2-point"`` and
``"3-point"`` (whole runs per Jacobian column): runs, CPU seconds and the Jacobian's error
at the truth against a reference (the 8th-order central difference of whole runs, ``h = 1e-4``
relative).

**The runs.**  Every run of the fit (the residuals, and each run of the finite differences) is
liefi's compiled fixed-step loop of :func:`~liefi.integrator.sensitivity.tangents` with no direction:
its kernel serves every value of the constants, while ``fi.run`` traces a ``from_mechanics`` system's
kernels again at each new value of its constants (tens of CPU seconds for this rattleback).

Run ``python examples/identify_rattleback.py [out.png]`` (default figure
``liefi-out/identify_rattleback.png``; the docs' figure is ``docs/gradients/identify_rattleback.png``).
The default uses the compiled path: the first run in a fresh cache compiles the rattleback's
kernels (minutes under load); numba's disk cache serves later processes.
"""

from __future__ import annotations

import sys
import time

import numpy as np

import liefi
from liefi.integrator.sensitivity import tangents

#: Kane & Levinson (1982) in SI units; the principal moments of (A, B, D) and the true (h, delta)
A_KL, B_KL, D_KL = 2e-4, 1.6e-3, 2e-5
TRUE = dict(h=0.01, delta=0.5 * float(np.arctan2(2 * D_KL, B_KL - A_KL)))
I1, I2 = np.linalg.eigvalsh([[A_KL, D_KL], [D_KL, B_KL]])
KNOWN = dict(a=0.20, b=0.03, c=0.02, m=1.0, g=9.81, I1=float(I1), I2=float(I2), C=1.7e-3)
FIT = ("h", "delta")
#: weights of the 8th-order central difference, (f(+k s) - f(-k s)) for k = 1..4
C8 = np.array([4 / 5, -1 / 5, 4 / 105, -1 / 280])


def rattleback_model():
    """The Kane model: ``(KanesMethod, {symbol: value})`` with ``h`` and ``delta`` among the constants."""
    import sympy
    import sympy.physics.mechanics as me

    a, b, c, h, m, g, I1, I2, C, delta = sympy.symbols("a b c h m g I1 I2 C delta")
    q1, q2, q3 = me.dynamicsymbols("q1 q2 q3")
    u1, u2, u3 = me.dynamicsymbols("u1:4")
    N = me.ReferenceFrame("N")
    Y = N.orientnew("Y", "Axis", [q1, N.z])
    L = Y.orientnew("L", "Axis", [q2, Y.x])
    R = L.orientnew("R", "Axis", [q3, L.y])
    w = R.ang_vel_in(N)
    qd = sympy.solve([w.dot(R.x) - u1, w.dot(R.y) - u2, w.dot(R.z) - u3], [q1.diff(), q2.diff(), q3.diff()])
    kd = [s.diff() - qd[s.diff()] for s in (q1, q2, q3)]
    R.set_ang_vel(N, u1 * R.x + u2 * R.y + u3 * R.z)
    # the contact point of the ellipsoid (Kane & Levinson 1982, eqs. 16-18), from the mass centre G
    Gam = [N.z.dot(R.x), N.z.dot(R.y), N.z.dot(R.z)]
    eps = sympy.sqrt((a * Gam[0]) ** 2 + (b * Gam[1]) ** 2 + (c * Gam[2]) ** 2)
    r_GP = -a**2 * Gam[0] / eps * R.x - b**2 * Gam[1] / eps * R.y + (h - c**2 * Gam[2] / eps) * R.z
    P = me.Point("P")
    P.set_vel(N, 0)
    G = P.locatenew("G", -r_GP)
    G.v2pt_theory(P, N, R)
    cs, sn = sympy.cos(delta), sympy.sin(delta)  # principal axes = geometric axes turned by delta about R.z
    Ixx, Iyy, Ixy = I1 * cs**2 + I2 * sn**2, I1 * sn**2 + I2 * cs**2, (I2 - I1) * sn * cs
    body = me.RigidBody("rattleback", G, R, m, (me.inertia(R, Ixx, Iyy, C, Ixy, 0, 0), G))
    KM = me.KanesMethod(N, q_ind=[q1, q2, q3], u_ind=[u1, u2, u3], kd_eqs=kd)
    KM.kanes_equations([body], [(G, -m * g * N.z)])
    values = dict(KNOWN, **TRUE)
    return KM, {s: values[str(s)] for s in (a, b, c, h, m, g, I1, I2, C, delta)}


class Experiment:
    """The runs of the fit: the launch ``(q0, u0)``, the step, the samples; one run per parameter vector.

    ``runs`` counts the runs made (a tangent run counts one run plus its directions in ``directions``);
    ``backend``: ``"numba"`` (compiled run and tangents) or ``"numpy"``.
    """

    def __init__(self, system, *, t_final, dt, sample, backend, q0, u0):
        self.system, self.T, self.dt, self.backend = system, float(t_final), float(dt), backend
        self.q0, self.u0 = np.asarray(q0, float), np.asarray(u0, float)
        self.n_steps = int(round(self.T / self.dt))
        self.every = int(round(sample / self.dt))
        if self.n_steps * self.dt != self.T and abs(self.n_steps * self.dt - self.T) > 1e-12 * self.T:
            raise ValueError(f"t_final: take a multiple of dt = {dt:g}")
        if abs(self.every * self.dt - sample) > 1e-12:
            raise ValueError(f"sample: take a multiple of dt = {dt:g}")
        self.saved = np.arange(0, self.n_steps + 1, self.every)
        self.t = self.saved * self.dt
        self.engine = "numba" if backend != "numpy" else "python"
        self.gains = None
        self.runs = self.directions = 0

    def start(self, theta):
        """liefi's start ``z0`` of the launch at the constants ``theta`` (set on the system)."""
        self.system.constants = dict(zip(FIT, map(float, theta)))
        return self.system.state(self.q0, u=self.u0)

    def integrator(self, theta):
        z0 = self.start(theta)
        if self.gains is None:  # gains="auto" resolved once, at the first point, then held (a number of the runs)
            sol = liefi.FeedbackIntegrator(self.system, z0).run(self.T, dt=self.dt, scheme="imex-rk4",
                                                                 backend=self.backend, save_every=self.every)
            self.gains = sol.stability.gains
        return liefi.FeedbackIntegrator(self.system, z0, gains=self.gains), z0

    def attitude(self, theta):
        """``(q1, q2, q3)`` at the samples, ``(3, n_t)``: one run."""
        fi, z0 = self.integrator(theta)
        self.runs += 1
        # the fixed-step run with no tangent direction: the compiled loop of the tangents, which serves every
        # value of the constants (fi.run would trace the system's kernels again at each new value)
        Y, _ = tangents(fi, "imex-rk4", z0, self.dt, self.n_steps, self.saved, np.zeros((0, fi.n)),
                        engine=self.engine)
        return Y[:3]

    def start_derivative(self, theta, step=1e-3):
        """``d z0 / d theta_j`` (rows), the 8th-order central difference of the algebraic start (relative step)."""
        theta = np.asarray(theta, float)
        rows = []
        for j in range(theta.size):
            e = np.eye(theta.size)[j] * step * abs(theta[j])
            rows.append(sum(c * (self.start(theta + k * e) - self.start(theta - k * e))
                            for k, c in zip(range(1, 5), C8)) / (step * abs(theta[j])))
        self.start(theta)
        return np.array(rows)

    def jacobian(self, theta):
        """``(q, dq/dtheta)``: the attitude ``(3, n_t)`` and its derivative ``(3, n_t, 2)`` from liefi's tangents."""
        V = self.start_derivative(theta)
        fi, z0 = self.integrator(theta)
        consts = [str(s) for s in self.system.constant_names]
        Cdir = np.zeros((len(FIT), len(consts)))
        for j, nm in enumerate(FIT):
            Cdir[j, consts.index(nm)] = 1.0
        Y, S = tangents(fi, "imex-rk4", z0, self.dt, self.n_steps, self.saved, V, Cdir, engine=self.engine)
        self.runs += 1
        self.directions += len(FIT)
        return Y[:3], np.moveaxis(S[:, :3, :], 0, -1)


def fit(exp, data, sigma, x0, jac):
    """``least_squares`` from ``x0`` with ``jac`` (``"liefi"``, ``"2-point"``, ``"3-point"``): result and cost."""
    from scipy.optimize import least_squares

    exp.runs = exp.directions = 0

    def residuals(x):
        return ((exp.attitude(x) - data) / sigma)[:, 1:].ravel()  # the start is the known launch: no residual

    def jacobian(x):
        _, dq = exp.jacobian(x)
        return (dq / sigma)[:, 1:, :].reshape(-1, len(x))

    t0 = time.process_time()
    res = least_squares(residuals, x0, jac=jacobian if jac == "liefi" else jac, x_scale=np.abs(x0))
    return dict(res=res, cpu=time.process_time() - t0, runs=exp.runs, directions=exp.directions)


def uncertainty(exp, x, data, sigma):
    """``(sigma_theta, s, cov)``: standard errors from ``s^2 (J^T J)^-1`` at ``x``, ``s`` the residual's RMS."""
    q, dq = exp.jacobian(x)
    r = (q - data)[:, 1:].ravel()
    J = dq[:, 1:, :].reshape(-1, len(x))
    s2 = float(r @ r) / (r.size - len(x))
    cov = s2 * np.linalg.inv(J.T @ J)
    return np.sqrt(np.diag(cov)), np.sqrt(s2), cov


def main(out="liefi-out/identify_rattleback.png", *, t_final=3.0, dt=1e-3, sample=0.02, sigma=np.radians(0.2),
         seed=0, backend="numba", compare=("2-point", "3-point"), guess=(0.012, 0.02)):
    """Make the data, fit them with liefi's Jacobians and with finite differences; returns a dict of results."""
    t0 = time.process_time()
    KM, consts = rattleback_model()
    system = liefi.from_mechanics(KM, consts)
    built = time.process_time() - t0
    tilt = np.radians(0.5)
    exp = Experiment(system, t_final=t_final, dt=dt, sample=sample, backend=backend, q0=[0.0, tilt, tilt],
                     u0=[0.0, 0.0, 5.0])
    truth = np.array([TRUE[k] for k in FIT])
    clean = exp.attitude(truth)
    rng = np.random.default_rng(seed)
    data = clean + sigma * rng.standard_normal(clean.shape)
    x0 = np.array(guess, float)
    exp.attitude(x0), exp.jacobian(x0)  # compile, and gains="auto" resolved at the guess (held by every run)
    print(f"rattleback built in {built:.1f} s CPU; {clean.shape[1]} samples of (yaw, roll, pitch) over "
          f"{t_final:g} s, noise {np.degrees(sigma):g} degrees (seed {seed}); backend {backend}")

    fits = {"liefi": fit(exp, data, sigma, x0, "liefi")}
    for jac in compare:
        fits[jac] = fit(exp, data, sigma, x0, jac)
    x = fits["liefi"]["res"].x
    std, s, cov = uncertainty(exp, x, data, sigma)
    z = (x - truth) / std
    print(f"residual RMS {np.degrees(s):.4f} degrees (noise {np.degrees(sigma):g}); correlation "
          f"{cov[0, 1] / (std[0] * std[1]):+.3f}")
    for j, nm in enumerate(FIT):
        print(f"  {nm:6s} = {x[j]:.6g} +- {std[j]:.2g}   (true {truth[j]:.6g}; {z[j]:+.2f} sigma)")

    # the Jacobian at the truth: liefi's and least_squares' differences against the 8th-order reference
    _, Jl = exp.jacobian(truth)
    ref = np.stack([sum(c * (exp.attitude(truth + k * e) - exp.attitude(truth - k * e)) for k, c in
                        zip(range(1, 5), C8)) / (1e-4 * truth[j])
                    for j, e in enumerate(np.diag(1e-4 * truth))], -1)
    from scipy.optimize._numdiff import approx_derivative

    def flat(x_):
        return exp.attitude(x_).ravel()

    jac_err = {"liefi": float(np.max(np.abs(Jl - ref)) / np.max(np.abs(ref)))}
    for jac in compare:
        Jf = approx_derivative(flat, truth, method=jac).reshape(ref.shape)
        jac_err[jac] = float(np.max(np.abs(Jf - ref)) / np.max(np.abs(ref)))
    rows = ["| Jacobian | runs (+ tangent directions) | CPU s | h | delta | cost | Jacobian error at the truth |",
            "|---|---|---|---|---|---|---|"]
    for name, f in fits.items():
        extra = f" (+ {f['directions']})" if f["directions"] else ""
        rows.append(f"| {name} | {f['runs']}{extra} | {f['cpu']:.2f} | {f['res'].x[0]:.8g} | {f['res'].x[1]:.8g} | "
                    f"{f['res'].cost:.6g} | {jac_err[name]:.1e} |")
    table = "\n".join(rows)
    print(table)
    if out:
        figure(out, exp, data, x, sigma)
    return dict(fit=x, std=std, z=z, truth=truth, fits=fits, jac_err=jac_err, table=table, s=s, sigma=sigma,
                exp=exp, data=data)


def figure(out, exp, data, x, sigma):
    """Roll and pitch: the samples against the fitted run, and the residuals."""
    import os

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    q = exp.attitude(x)
    fig, axes = plt.subplots(2, 1, figsize=(8.0, 5.2), sharex=True, height_ratios=[3, 1.3])
    for i, (nm, col) in enumerate((("roll $q_2$", "C0"), ("pitch $q_3$", "C1")), start=1):
        axes[0].plot(exp.t, np.degrees(data[i]), ".", color=col, ms=3, alpha=0.6, label=f"{nm}: samples")
        axes[0].plot(exp.t, np.degrees(q[i]), "-", color=col, lw=1.2, label=f"{nm}: fitted run")
        axes[1].plot(exp.t, np.degrees(data[i] - q[i]), ".", color=col, ms=2.5)
    axes[1].axhline(0.0, color="0.5", lw=0.6)
    for k in (-2, 2):
        axes[1].axhline(k * np.degrees(sigma), color="0.5", lw=0.6, ls="--")
    axes[0].set_ylabel("angle (degrees)")
    axes[1].set_ylabel("residual (deg)")
    axes[1].set_xlabel("t (s)")
    axes[0].legend(fontsize=9, ncol=2, loc="upper right")
    axes[0].set_title(f"Rattleback identified from noisy attitude: h = {x[0] * 1e3:.3f} mm, "
                      f"delta = {np.degrees(x[1]):.3f} degrees")
    fig.tight_layout()
    os.makedirs(os.path.dirname(out) or ".", exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    print(f"figure: {out}")


if __name__ == "__main__":
    main(*(sys.argv[1:2] or []))
