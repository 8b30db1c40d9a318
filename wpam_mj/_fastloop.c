/* Compiled twin of the reference simulation loop `wpam_mj.simulate.run_python`.

   A line-by-line port of run_python + Plant.advance (wpam_mj/simulate.py),
   PoFeedback.update (wpam_mj/control.py), MuscleModel.tension/friction
   (wpam_mj/muscle.py), BraidGeometry.area/volume/diameter (wpam_mj/geometry.py) and
   mass_flow/iso6358_psi (wpam_mj/pneumatics.py). See those modules for the physics and
   its sources (paper eqs. 1-7; Chou & Hannaford 1996; ISO 6358).

   Bit-identical to the Python loop, by construction:
     - Python floats are IEEE doubles; every expression below is evaluated in the same
       order as its Python original (a * b * c is (a * b) * c, left to right).
     - Compiled with -ffp-contract=off and without -ffast-math, so no a * b + c is fused
       into one FMA and nothing is reassociated (wpam_mj/fastloop.py sets the flags).
     - The only libm call is sqrt, which IEEE 754 requires to be correctly rounded.
       Constants that Python derives with `**` or math.expm1 (b^2, 4 pi n^2, lag alpha)
       are computed by Python and passed in (see the K_* layout), not recomputed here.
     - min/max follow Python's builtins: max(a, b) is b if b > a else a (first wins ties).
   tests/test_fastloop.py checks every recorded array for equality bit for bit.

   Units: SI throughout (m, m/s, Pa, N, kg/s, s), as in the Python modules. */

#include <math.h>
#include <stdlib.h>

#include <mujoco/mujoco.h>

/* Layout of the `consts` array; must match `_CONSTS` in wpam_mj/fastloop.py
   (checked at load time through wpam_n_consts). */
enum {
  /* RunConstants (wpam_mj/simulate.py) */
  K_DT,              /* physics time step [s] */
  K_RECORD_EVERY,    /* record every this many steps [1] */
  K_FEEDBACK,        /* 1: Po from PoFeedback, 0: Po from the drive [1] */
  K_LAG_ALPHA,       /* 1 - exp(-dt / tau) of the regulator lag [1] */
  K_DELAY_STEPS,     /* regulator dead time [steps] */
  K_ATMOSPHERE,      /* [Pa] */
  K_P_MAX,           /* regulator command clamp [Pa] */
  K_CONDUCTANCE_I,   /* ISO 6358 sonic conductance C of the Pi line [m^3/(s Pa)] */
  K_CONDUCTANCE_O,   /* ISO 6358 sonic conductance C of the Po line [m^3/(s Pa)] */
  K_CRITICAL_RATIO,  /* ISO 6358 b [1] */
  K_TUBE_VOLUME,     /* [m^3] */
  K_BAG_VOLUME,      /* outer bag volume [m^3] */
  /* wpam_mj.pneumatics module constants */
  K_RT0,             /* R_AIR * T_0 [J/kg] */
  K_RHO0,            /* RHO_0 [kg/m^3] */
  K_R_LAMINAR,       /* R_LAMINAR [1] */
  /* MuscleModel */
  K_OUTPUT_COEFF,    /* Kf [1] */
  K_FRICTION_COEFF,  /* mu [1] */
  K_FRICTION_CONST,  /* F_f0 [N] */
  K_AXIAL_AREA,      /* A_ax [m^2] */
  K_PI_KR,           /* math.pi * rubber_stiffness [N/m] */
  K_NATURAL_DIAMETER,/* D0 [m] */
  /* BraidGeometry */
  K_NATURAL_LENGTH,  /* L0 [m] */
  K_THREAD_SQ,       /* thread_length ** 2 [m^2] */
  K_VOLUME_DENOM,    /* 4.0 * math.pi * turns ** 2 [1] (area and volume) */
  K_DIAMETER_DENOM,  /* turns * math.pi [1] */
  /* PoFeedback (wpam_mj/control.py) */
  K_KP,              /* [MPa/mm] */
  K_KI,              /* [MPa/(mm s)] */
  K_KD,              /* [MPa s/mm]; 0 unless PID */
  K_TF,              /* derivative filter time constant [s] */
  K_PO_LO,           /* p_min [Pa] */
  K_PO_HI,           /* po_cap [Pa] */
  K_MM,              /* m per mm */
  K_MPA,             /* Pa per MPa */
  K_INTEGRAL0,       /* initial integral [mm s] (bumpless start) */
  /* where the loop reads and writes MuJoCo (looked up by name in Python) */
  K_QPOS_ADR,        /* qpos address of the contraction joint */
  K_DOF_ADR,         /* dof address of the contraction joint */
  K_ACTUATOR_ID,     /* the muscle motor */
  K_TENDON_ID,       /* the muscle tendon */
  K_COUNT
};

/* Reasons written to fail_info[0] when wpam_run returns a step index + 1. */
enum {
  FAIL_CONTRACTION = 1,  /* fail_info[1] = x [m] */
  FAIL_PRESSURE = 2,     /* fail_info[1] = Pi, fail_info[2] = Po, absolute [Pa] */
};

/* Return codes below zero: the call itself was wrong, nothing was simulated. */
enum { ERR_BAD_RECORD = -1, ERR_NO_MEMORY = -2 };

int wpam_n_consts(void) { return K_COUNT; }

/* 1 when the headers this file was compiled with match the loaded libmujoco. */
int wpam_abi_ok(void) { return mj_version() == mjVERSION_HEADER; }

static double py_max(double a, double b) { return b > a ? b : a; }
static double py_min(double a, double b) { return b < a ? b : a; }

/* ---- BraidGeometry (wpam_mj/geometry.py) ---- */

static double geom_diameter(const double* k, double x) {
  double L = k[K_NATURAL_LENGTH] - x;
  return sqrt(k[K_THREAD_SQ] - L * L) / k[K_DIAMETER_DENOM];
}

static double geom_volume(const double* k, double x) {
  double L = k[K_NATURAL_LENGTH] - x;
  return L * (k[K_THREAD_SQ] - L * L) / k[K_VOLUME_DENOM];
}

static double geom_area(const double* k, double x) {
  double L = k[K_NATURAL_LENGTH] - x;
  return (3.0 * L * L - k[K_THREAD_SQ]) / k[K_VOLUME_DENOM];
}

/* ---- MuscleModel (wpam_mj/muscle.py); gauge pressures ---- */

static double muscle_rubber_force(const double* k, double x) {
  return k[K_PI_KR] * (geom_diameter(k, x) - k[K_NATURAL_DIAMETER]);
}

static double muscle_tension(const double* k, double x, double pi, double po) {
  double dp = pi > po ? pi - po : 0.0;
  return (k[K_OUTPUT_COEFF] * dp * geom_area(k, x) - k[K_AXIAL_AREA] * po
          - muscle_rubber_force(k, x));
}

static double muscle_friction(const double* k, double x, double pi, double po) {
  double dp = pi > po ? pi - po : 0.0;
  return k[K_FRICTION_COEFF] * dp * geom_area(k, x) + k[K_FRICTION_CONST];
}

/* ---- pneumatics (wpam_mj/pneumatics.py); absolute pressures ---- */

static double iso6358_psi(const double* k, double r, double b) {
  double q;
  if (r <= b) return 1.0;
  if (r <= k[K_R_LAMINAR]) {
    q = (r - b) / (1.0 - b);
    return sqrt(1.0 - q * q);
  }
  q = (k[K_R_LAMINAR] - b) / (1.0 - b);
  return sqrt(1.0 - q * q) * (1.0 - r) / (1.0 - k[K_R_LAMINAR]);
}

static double mass_flow(const double* k, double p_source, double p_chamber, double c) {
  double b = k[K_CRITICAL_RATIO];
  if (p_source >= p_chamber)
    return c * k[K_RHO0] * p_source * iso6358_psi(k, p_chamber / p_source, b);
  return -c * k[K_RHO0] * p_chamber * iso6358_psi(k, p_source / p_chamber, b);
}

/* ---- PoFeedback (wpam_mj/control.py) ---- */

typedef struct {
  double integral;    /* mm s */
  double derivative;  /* mm/s */
  double e_prev;      /* mm */
  int has_prev;       /* 0 until the first update (Python: e_prev is None) */
} Feedback;

static double feedback_update(const double* k, Feedback* f, double x, double x_ref) {
  double e = (x - x_ref) / k[K_MM];
  double e_prev = f->has_prev ? f->e_prev : e;
  double integral, u;
  f->derivative = (k[K_TF] * f->derivative + (e - e_prev)) / (k[K_TF] + k[K_DT]);
  integral = f->integral + e * k[K_DT];
  u = (k[K_KP] * e + k[K_KI] * integral + k[K_KD] * f->derivative) * k[K_MPA];
  if (u > k[K_PO_HI]) {
    u = k[K_PO_HI];
    if (e < 0.0) f->integral = integral;
  } else if (u < k[K_PO_LO]) {
    u = k[K_PO_LO];
    if (e > 0.0) f->integral = integral;
  } else {
    f->integral = integral;
  }
  f->e_prev = e;
  f->has_prev = 1;
  return u;
}

/* ---- Plant (wpam_mj/simulate.py) ---- */

typedef struct {
  double set_i, set_o;        /* regulator set points, gauge [Pa] */
  double p_i, p_o;            /* chamber pressures, absolute [Pa] */
  double *queue_i, *queue_o;  /* commands in flight (dead time) [Pa] */
  int head, delay;
} Plant;

/* One step at contraction x [m], velocity v [m/s]: writes tension and friction [N].
   Returns 0, or FAIL_PRESSURE with the new state left in the plant. */
static int plant_advance(const double* k, Plant* s, double x, double v, double pi_cmd,
                         double po_cmd, double* tension, double* friction) {
  double pa, p_i, p_o, area, vol, m_i, m_o, v_i, v_o, held;
  /* regulators: dead time, then first-order lag */
  if (s->delay) {
    int h = s->head;
    held = s->queue_i[h]; s->queue_i[h] = pi_cmd; pi_cmd = held;
    held = s->queue_o[h]; s->queue_o[h] = po_cmd; po_cmd = held;
    s->head = (h + 1) % s->delay;
  }
  s->set_i += k[K_LAG_ALPHA] * (py_min(py_max(pi_cmd, 0.0), k[K_P_MAX]) - s->set_i);
  s->set_o += k[K_LAG_ALPHA] * (py_min(py_max(po_cmd, 0.0), k[K_P_MAX]) - s->set_o);
  /* muscle force from the chamber gauge pressures */
  pa = k[K_ATMOSPHERE];
  p_i = s->p_i;
  p_o = s->p_o;
  *tension = muscle_tension(k, x, p_i - pa, p_o - pa);
  *friction = muscle_friction(k, x, p_i - pa, p_o - pa);
  /* chambers */
  area = geom_area(k, x);
  vol = geom_volume(k, x);
  m_i = mass_flow(k, s->set_i + pa, p_i, k[K_CONDUCTANCE_I]);
  m_o = mass_flow(k, s->set_o + pa, p_o, k[K_CONDUCTANCE_O]);
  v_i = vol + k[K_TUBE_VOLUME];
  v_o = k[K_BAG_VOLUME] + k[K_TUBE_VOLUME] - vol - k[K_AXIAL_AREA] * x;
  s->p_i = p_i + k[K_DT] * (k[K_RT0] * m_i - p_i * area * v) / v_i;
  s->p_o = p_o + k[K_DT] * (k[K_RT0] * m_o + p_o * (area + k[K_AXIAL_AREA]) * v) / v_o;
  if (!(s->p_i > 0.0 && s->p_o > 0.0)) return FAIL_PRESSURE;
  return 0;
}

/* ---- the loop (run_python) ---- */

/* Run n physics steps of model m from state d.

   pi_cmd, po_cmd, x_ref: drive samples [Pa, Pa, m], length n (x_ref NaN in open loop).
   rec: (9, n_rec) C-contiguous, rows t, x, v, x_ref, pi_gauge, po_gauge, pi_cmd,
     po_cmd, tension, a column every K_RECORD_EVERY steps, as run_python fills it.
   fail_info: 3 doubles, written on divergence (FAIL_* code, then its values).
   Returns 0 when all steps ran, step + 1 when the state diverged at `step`, or a
   negative ERR_* code when the arguments were inconsistent.
   Writes d (the MuJoCo state), d->ctrl and m->tendon_frictionloss as run_python does. */
int wpam_run(mjModel* m, mjData* d, const double* consts, int n, const double* pi_cmd,
             const double* po_cmd, const double* x_ref, double* rec, int n_rec,
             double* fail_info) {
  const double* k = consts;
  const int record_every = (int)k[K_RECORD_EVERY];
  const int feedback = k[K_FEEDBACK] != 0.0;
  const int qpos_adr = (int)k[K_QPOS_ADR], dof_adr = (int)k[K_DOF_ADR];
  const int actuator = (int)k[K_ACTUATOR_ID], tendon = (int)k[K_TENDON_ID];
  Plant plant = {0.0, 0.0, k[K_ATMOSPHERE], k[K_ATMOSPHERE], NULL, NULL, 0,
                 (int)k[K_DELAY_STEPS]};
  Feedback pid = {k[K_INTEGRAL0], 0.0, 0.0, 0};
  int step, j = 0, status = 0;

  if (record_every < 1 || n < 0 || (n > 0 && n_rec < (n - 1) / record_every + 1))
    return ERR_BAD_RECORD;
  if (plant.delay) {
    /* calloc: all-zero bits are +0.0, the Python queue's [0.0] * delay_steps */
    plant.queue_i = calloc(2 * (size_t)plant.delay, sizeof(double));
    if (!plant.queue_i) return ERR_NO_MEMORY;
    plant.queue_o = plant.queue_i + plant.delay;
  }

  for (step = 0; step < n; step++) {
    double x = d->qpos[qpos_adr];
    double v = d->qvel[dof_adr];
    double pi_gauge, po_gauge, pi_c, xr, po_c, tension, friction;
    if (!(-1.0 < x && x < 1.0)) {
      fail_info[0] = FAIL_CONTRACTION;
      fail_info[1] = x;
      status = step + 1;
      break;
    }
    pi_gauge = plant.p_i - k[K_ATMOSPHERE];
    po_gauge = plant.p_o - k[K_ATMOSPHERE];
    pi_c = pi_cmd[step];
    xr = x_ref[step];
    po_c = feedback ? feedback_update(k, &pid, x, xr) : po_cmd[step];
    if (plant_advance(k, &plant, x, v, pi_c, po_c, &tension, &friction)) {
      fail_info[0] = FAIL_PRESSURE;
      fail_info[1] = plant.p_i;
      fail_info[2] = plant.p_o;
      status = step + 1;
      break;
    }
    d->ctrl[actuator] = -tension;
    m->tendon_frictionloss[tendon] = friction;
    if (step % record_every == 0) {
      rec[0 * n_rec + j] = step * k[K_DT];
      rec[1 * n_rec + j] = x;
      rec[2 * n_rec + j] = v;
      rec[3 * n_rec + j] = xr;
      rec[4 * n_rec + j] = pi_gauge;
      rec[5 * n_rec + j] = po_gauge;
      rec[6 * n_rec + j] = pi_c;
      rec[7 * n_rec + j] = po_c;
      rec[8 * n_rec + j] = tension;
      rec[9 * n_rec + j] = friction;
      rec[10 * n_rec + j] = plant.set_i;
      rec[11 * n_rec + j] = plant.set_o;
      j++;
    }
    mj_step(m, d);
  }
  free(plant.queue_i);
  return status;
}
