/* Compiled twin of the reference simulation loop `wpam_mj.simulate.run_python`.

   A line-by-line port of run_python (wpam_mj/simulate.py), Plant.advance
   (wpam_mj/plant.py), Regulator, Chamber, mass_flow and iso6358_psi
   (wpam_mj/pneumatics.py), PoFeedback.update (wpam_mj/control.py),
   MuscleModel.tension/friction (wpam_mj/muscle.py) and BraidGeometry.area/volume/diameter
   (wpam_mj/geometry.py), each under the same name. See those modules for the physics and
   its sources (paper eqs. 1-7; Chou & Hannaford 1996; ISO 6358).

   Bit-identical to the Python loop, by construction:
     - Python floats are IEEE doubles; every expression below is evaluated in the same
       order as its Python original (a * b * c is (a * b) * c, left to right).
     - Compiled with -ffp-contract=off and without -ffast-math, so no a * b + c is fused
       into one FMA and nothing is reassociated (wpam_mj/fastloop.py sets the flags).
     - The only libm call is sqrt, which IEEE 754 requires to be correctly rounded.
       Constants that Python derives with `**` or math.expm1 (b^2, 4 pi n^2, lag alpha)
       are computed by Python and passed in (see WPAM_CONSTANTS), not recomputed here.
     - min/max follow Python's builtins: max(a, b) is b if b > a else a (first wins ties).
   tests/test_fastloop.py checks every recorded array for equality bit for bit.

   Units: SI throughout (m, m/s, Pa, N, kg/s, s), as in the Python modules. */

#include <math.h>
#include <stdlib.h>

#include <mujoco/mujoco.h>

/* The per-run constants, in the order of the `consts` array: X(ENUM_NAME, python_name).
   `wpam_const_names` returns the python names; wpam_mj/fastloop.py fills the array by
   these names (a field of RunConstants, MuscleModel or MuscleIndex under its own name, or
   one of its derived values) and refuses to load this library when a name is missing on
   either side. Integers (steps, flags, indices) are stored exactly as doubles. */
#define WPAM_CONSTANTS(X)                                                          \
  /* RunConstants (wpam_mj/loop_contract.py) */                                    \
  X(DT, dt)                          /* physics time step [s] */                   \
  X(RECORD_EVERY, record_every)      /* record every this many steps [1] */        \
  X(CONTROLLER, controller)          /* index into WPAM_CONTROLLERS */             \
  X(LAG_ALPHA, lag_alpha)            /* 1 - exp(-dt / tau) of the regulator lag */ \
  X(DELAY_STEPS, delay_steps)        /* regulator dead time [steps] */             \
  X(ATMOSPHERE, atmosphere)          /* [Pa] */                                    \
  X(P_MAX, p_max)                    /* regulator command clamp [Pa] */            \
  X(CONDUCTANCE_I, conductance_i)    /* ISO 6358 C of the Pi line [m^3/(s Pa)] */  \
  X(CONDUCTANCE_O, conductance_o)    /* ISO 6358 C of the Po line [m^3/(s Pa)] */  \
  X(CRITICAL_RATIO, critical_ratio)  /* ISO 6358 b [1] */                          \
  X(TUBE_VOLUME, tube_volume)        /* [m^3] */                                   \
  X(BAG_VOLUME, bag_volume)          /* outer bag volume [m^3] */                  \
  X(START_AT_REST, start_at_rest)    /* 1: plant_rest at the first commands */     \
  /* wpam_mj.pneumatics module constants */                                        \
  X(RT0, rt0)                        /* R_AIR * T_0 [J/kg] */                      \
  X(RHO0, rho0)                      /* RHO_0 [kg/m^3] */                          \
  X(R_LAMINAR, r_laminar)            /* R_LAMINAR [1] */                           \
  /* MuscleModel (wpam_mj/muscle.py) */                                            \
  X(OUTPUT_COEFF, output_coeff)      /* Kf [1] */                                  \
  X(FRICTION_COEFF, friction_coeff)  /* mu [1] */                                  \
  X(FRICTION_CONST, friction_const)  /* F_f0 [N] */                                \
  X(AXIAL_AREA, axial_area)          /* A_ax [m^2] */                              \
  X(RUBBER_STIFFNESS, rubber_stiffness) /* K_R [N/m] */                            \
  X(NATURAL_DIAMETER, natural_diameter) /* D0 [m] */                               \
  /* BraidGeometry (wpam_mj/geometry.py) */                                        \
  X(NATURAL_LENGTH, natural_length)  /* L0 [m] */                                  \
  X(THREAD_SQ, thread_sq)            /* thread_length ** 2 [m^2] */                \
  X(VOLUME_DENOM, volume_denom)      /* 4.0 * math.pi * turns ** 2 [1] */          \
  X(DIAMETER_DENOM, diameter_denom)  /* turns * math.pi [1] */                     \
  /* PoFeedback (wpam_mj/control.py); zeros for the open loop */                  \
  X(KP, kp)                          /* [u/mm] */                                  \
  X(KI, ki)                          /* [u/(mm s)] */                              \
  X(KD, kd)                          /* [u s/mm]; 0 unless PID */                  \
  X(TF, tf)                          /* derivative filter time constant [s] */     \
  X(PO_LO, po_lo)                    /* p_min [Pa] */                              \
  X(PO_HI, po_hi)                    /* po_cap [Pa] */                             \
  X(MM, mm)                          /* m per mm */                                \
  X(PA_PER_UNIT, pa_per_unit)        /* Po command [Pa] per controller unit u */  \
  X(INTEGRAL0, integral0)            /* initial integral [mm s] (bumpless start) */ \
  /* MuscleIndex: where the loop reads and writes MuJoCo (looked up by name) */     \
  X(QPOS, qpos)                      /* qpos address of the contraction joint */   \
  X(DOF, dof)                        /* dof address of the contraction joint */    \
  X(ACTUATOR, actuator)              /* the muscle motor */                        \
  X(TENDON, tendon)                  /* the muscle tendon */

/* Rows of the recording array: REC_FIELDS of wpam_mj/loop_contract.py, checked by name
   in the same way (`wpam_record_fields`). */
#define WPAM_RECORD(F)                                                             \
  F(TIME, time) F(X, x) F(VELOCITY, velocity) F(X_REF, x_ref) F(PI, pi) F(PO, po)   \
  F(PI_CMD, pi_cmd) F(PO_CMD, po_cmd) F(TENSION, tension) F(FRICTION, friction)     \
  F(PI_REG, pi_reg) F(PO_REG, po_reg)

/* The controllers this file implements: names of wpam_mj.control.CONTROLLERS. Python
   runs any other controller in its own loop (`wpam_mj.fastloop.compiled_controllers`). */
#define WPAM_CONTROLLERS(F) F(OPEN, open) F(PI, pi) F(PID, pid) F(PI_FF, pi_ff)

#define AS_CONST_ENUM(NAME, name) K_##NAME,
#define AS_CONTROLLER_ENUM(NAME, name) CTRL_##NAME,
#define AS_RECORD_ENUM(NAME, name) R_##NAME,
#define AS_STRING(NAME, name) #name ","

enum { WPAM_CONSTANTS(AS_CONST_ENUM) K_COUNT };
enum { WPAM_RECORD(AS_RECORD_ENUM) R_COUNT };
enum { WPAM_CONTROLLERS(AS_CONTROLLER_ENUM) CTRL_COUNT };

/* Comma-separated names, in layout order (a trailing comma ends the list). */
const char* wpam_const_names(void) { return WPAM_CONSTANTS(AS_STRING); }
const char* wpam_record_fields(void) { return WPAM_RECORD(AS_STRING); }
const char* wpam_controllers(void) { return WPAM_CONTROLLERS(AS_STRING); }

/* Reasons written to fail_info[0] when wpam_run returns a step index + 1. */
enum {
  FAIL_CONTRACTION = 1,  /* fail_info[1] = x [m] */
  FAIL_PRESSURE = 2,     /* fail_info[1] = Pi, fail_info[2] = Po, absolute [Pa] */
};

/* Return codes below zero: the call itself was wrong, nothing was simulated. */
enum { ERR_BAD_RECORD = -1, ERR_NO_MEMORY = -2, ERR_BAD_CONTROLLER = -3 };

/* 1 when the headers this file was compiled with match the loaded libmujoco. */
int wpam_abi_ok(void) { return mj_version() == mjVERSION_HEADER; }

/* math.pi: the literal rounds to the same double (M_PI is not part of C11). */
#define PI 3.14159265358979323846

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
  return PI * k[K_RUBBER_STIFFNESS] * (geom_diameter(k, x) - k[K_NATURAL_DIAMETER]);
}

static double muscle_tension(const double* k, double x, double pi, double po) {
  double dp = pi > po ? pi - po : 0.0;
  return (k[K_OUTPUT_COEFF] * (dp * geom_area(k, x) - muscle_rubber_force(k, x))
          - k[K_AXIAL_AREA] * po);
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

/* ---- controllers (wpam_mj/control.py): OpenLoop passes the drive's Po through;
   PIControl and PIDControl are PoFeedback, PI with kd = 0; PIFlowFeedforward is PI plus
   the drive's Po command as feedforward (po_ff; 0.0 for the others) ---- */

typedef struct {
  double integral;    /* mm s */
  double derivative;  /* mm/s */
  double e_prev;      /* mm */
  int has_prev;       /* 0 until the first update (Python: e_prev is None) */
} Feedback;

static double feedback_update(const double* k, Feedback* f, double x, double x_ref,
                              double po_ff) {
  double e = (x - x_ref) / k[K_MM];
  double e_prev = f->has_prev ? f->e_prev : e;
  double integral, u;
  f->derivative = (k[K_TF] * f->derivative + (e - e_prev)) / (k[K_TF] + k[K_DT]);
  integral = f->integral + e * k[K_DT];
  u = (k[K_KP] * e + k[K_KI] * integral + k[K_KD] * f->derivative) * k[K_PA_PER_UNIT]
      + po_ff;
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

/* ---- Regulator and Chamber (wpam_mj/pneumatics.py) ---- */

typedef struct {
  double set_point;  /* gauge [Pa] */
  double* queue;     /* commands in flight (dead time) [Pa]; NULL without dead time */
  int head, delay;
} Regulator;

static void regulator_rest(const double* k, Regulator* r, double command) {
  int i;
  for (i = 0; i < r->delay; i++) r->queue[i] = command;
  r->set_point = py_min(py_max(command, 0.0), k[K_P_MAX]);
}

static double regulator_update(const double* k, Regulator* r, double command) {
  double clamped;
  if (r->delay) {
    int h = r->head;
    double held = r->queue[h];
    r->queue[h] = command;
    command = held;
    r->head = (h + 1) % r->delay;
  }
  clamped = py_min(py_max(command, 0.0), k[K_P_MAX]);
  r->set_point += k[K_LAG_ALPHA] * (clamped - r->set_point);
  return r->set_point;
}

typedef struct {
  double conductance;  /* ISO 6358 C [m^3/(s Pa)] */
  double pressure;     /* absolute [Pa] */
} Chamber;

static double chamber_step(const double* k, Chamber* c, double p_source, double volume,
                           double dvdx, double v) {
  double p = c->pressure;
  double m = mass_flow(k, p_source, p, c->conductance);
  c->pressure = p + k[K_DT] * (k[K_RT0] * m - p * dvdx * v) / volume;
  return c->pressure;
}

/* ---- Plant (wpam_mj/plant.py) ---- */

typedef struct {
  Regulator regulator_i, regulator_o;
  Chamber chamber_i, chamber_o;
} Plant;

static void plant_rest(const double* k, Plant* s, double pi_cmd, double po_cmd) {
  regulator_rest(k, &s->regulator_i, pi_cmd);
  regulator_rest(k, &s->regulator_o, po_cmd);
  s->chamber_i.pressure = s->regulator_i.set_point + k[K_ATMOSPHERE];
  s->chamber_o.pressure = s->regulator_o.set_point + k[K_ATMOSPHERE];
}

/* One step at contraction x [m], velocity v [m/s]: writes tension and friction [N].
   Returns 0, or FAIL_PRESSURE with the new state left in the plant. */
static int plant_advance(const double* k, Plant* s, double x, double v, double pi_cmd,
                         double po_cmd, double* tension, double* friction) {
  double set_i = regulator_update(k, &s->regulator_i, pi_cmd);
  double set_o = regulator_update(k, &s->regulator_o, po_cmd);
  double pa = k[K_ATMOSPHERE];
  double pi = s->chamber_i.pressure - pa, po = s->chamber_o.pressure - pa;
  double area, vol, p_i, p_o;
  *tension = muscle_tension(k, x, pi, po);
  *friction = muscle_friction(k, x, pi, po);
  /* chamber volumes and dV/dx (wpam_mj/pneumatics.py) */
  area = geom_area(k, x);
  vol = geom_volume(k, x);
  p_i = chamber_step(k, &s->chamber_i, set_i + pa, vol + k[K_TUBE_VOLUME], area, v);
  p_o = chamber_step(k, &s->chamber_o, set_o + pa,
                     k[K_BAG_VOLUME] + k[K_TUBE_VOLUME] - vol - k[K_AXIAL_AREA] * x,
                     -(area + k[K_AXIAL_AREA]), v);
  if (!(p_i > 0.0 && p_o > 0.0)) return FAIL_PRESSURE;
  return 0;
}

/* ---- the loop (wpam_mj/simulate.py: run_python) ---- */

/* Run n physics steps of model m from state d.

   pi_cmd, po_cmd, x_ref: drive samples [Pa, Pa, m], length n (x_ref NaN in open loop).
   rec: (R_COUNT, n_rec) C-contiguous, one row per WPAM_RECORD field, a column every
     K_RECORD_EVERY steps, as run_python fills it.
   fail_info: 3 doubles, written on divergence (FAIL_* code, then its values).
   Returns 0 when all steps ran, step + 1 when the state diverged at `step`, or a
   negative ERR_* code when the arguments were inconsistent.
   Writes d (the MuJoCo state), d->ctrl and m->tendon_frictionloss as run_python does. */
int wpam_run(mjModel* m, mjData* d, const double* consts, int n, const double* pi_cmd,
             const double* po_cmd, const double* x_ref, double* rec, int n_rec,
             double* fail_info) {
  const double* k = consts;
  const int record_every = (int)k[K_RECORD_EVERY];
  const int controller = (int)k[K_CONTROLLER];
  const int delay = (int)k[K_DELAY_STEPS];
  const int qpos_adr = (int)k[K_QPOS], dof_adr = (int)k[K_DOF];
  const int actuator = (int)k[K_ACTUATOR], tendon = (int)k[K_TENDON];
  Plant plant = {{0.0, NULL, 0, delay}, {0.0, NULL, 0, delay},
                 {k[K_CONDUCTANCE_I], k[K_ATMOSPHERE]}, {k[K_CONDUCTANCE_O], k[K_ATMOSPHERE]}};
  Feedback pid = {k[K_INTEGRAL0], 0.0, 0.0, 0};
  double* queues = NULL;
  int step, j = 0, status = 0;

  if (controller < 0 || controller >= CTRL_COUNT) return ERR_BAD_CONTROLLER;
  if (record_every < 1 || n < 0 || (n > 0 && n_rec < (n - 1) / record_every + 1))
    return ERR_BAD_RECORD;
  if (delay) {
    /* calloc: all-zero bits are +0.0, the Python queue's [0.0] * delay_steps */
    queues = calloc(2 * (size_t)delay, sizeof(double));
    if (!queues) return ERR_NO_MEMORY;
    plant.regulator_i.queue = queues;
    plant.regulator_o.queue = queues + delay;
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
    pi_gauge = plant.chamber_i.pressure - k[K_ATMOSPHERE];
    po_gauge = plant.chamber_o.pressure - k[K_ATMOSPHERE];
    pi_c = pi_cmd[step];
    xr = x_ref[step];
    po_c = controller == CTRL_OPEN ? po_cmd[step]
         : feedback_update(k, &pid, x, xr, controller == CTRL_PI_FF ? po_cmd[step] : 0.0);
    if (step == 0 && k[K_START_AT_REST] != 0.0) { /* first commands held before the run */
      plant_rest(k, &plant, pi_c, po_c);
      pi_gauge = plant.chamber_i.pressure - k[K_ATMOSPHERE];
      po_gauge = plant.chamber_o.pressure - k[K_ATMOSPHERE];
    }
    if (plant_advance(k, &plant, x, v, pi_c, po_c, &tension, &friction)) {
      fail_info[0] = FAIL_PRESSURE;
      fail_info[1] = plant.chamber_i.pressure;
      fail_info[2] = plant.chamber_o.pressure;
      status = step + 1;
      break;
    }
    d->ctrl[actuator] = -tension;
    m->tendon_frictionloss[tendon] = friction;
    mj_step(m, d);
    if (step % record_every == 0) { /* the state at the start of this step */
      double* col = rec + j;
      col[R_TIME * n_rec] = step * k[K_DT];
      col[R_X * n_rec] = x;
      col[R_VELOCITY * n_rec] = v;
      col[R_X_REF * n_rec] = xr;
      col[R_PI * n_rec] = pi_gauge;
      col[R_PO * n_rec] = po_gauge;
      col[R_PI_CMD * n_rec] = pi_c;
      col[R_PO_CMD * n_rec] = po_c;
      col[R_TENSION * n_rec] = tension;
      col[R_FRICTION * n_rec] = friction;
      col[R_PI_REG * n_rec] = plant.regulator_i.set_point;
      col[R_PO_REG * n_rec] = plant.regulator_o.set_point;
      j++;
    }
  }
  free(queues);
  return status;
}
