/* The Instances of every mjData: handles a copied mjData cannot mistake, and the lookup
   of d's own Instance, current for the model it steps (instance_of).

   MuJoCo keeps one uintptr_t per instance in d->plugin_data and copies it raw when an
   MjData is pickled, into a data that is not the one it was made for (or into another
   process, where it means nothing). So plugin_data holds a handle, index + 1 into this
   library's table of Instances, never a pointer: a handle is looked up, bounds-checked
   and its Instance's owner compared with d before anything is read through it. A data
   holding another's handle (a pickled copy) finds or makes its own. The table grows in
   chunks that never move, so steps on other threads read it without a lock. */

#include <pthread.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

#include "muscle_plugin.h"

#define CHUNK_SLOTS 64
#define MAX_CHUNKS 16384
static Instance* chunks[MAX_CHUNKS];
static atomic_int nslot;  /* slots handed out: handles 1 .. nslot are valid indices */
static pthread_mutex_t table_lock = PTHREAD_MUTEX_INITIALIZER;

Instance* slot(uintptr_t handle) {
  uintptr_t i = handle - 1;
  if (handle == 0 || handle > (uintptr_t)atomic_load(&nslot)) return NULL;
  return &chunks[i / CHUNK_SLOTS][i % CHUNK_SLOTS];
}

int owned(const Instance* k, const mjData* d, int instance) {
  return k && k->in_use && k->owner == d && k->instance == instance;
}

/* The handle of d's Instance of `instance`, 0 if it has none. */
uintptr_t find_owned(const mjData* d, int instance) {
  uintptr_t h, n = (uintptr_t)atomic_load(&nslot);
  for (h = 1; h <= n; h++)
    if (owned(slot(h), d, instance)) return h;
  return 0;
}

/* A new Instance owned by (d, instance) holding *k: a freed slot, or one appended (its
   chunk allocated first, then published by nslot); 0 when memory runs out. */
uintptr_t new_slot(const mjData* d, int instance, const Instance* k) {
  uintptr_t h, n;
  Instance* fresh;
  pthread_mutex_lock(&table_lock);
  n = (uintptr_t)atomic_load(&nslot);
  for (h = 1; h <= n && slot(h)->in_use; h++) continue;
  if (h > n) {
    uintptr_t chunk = n / CHUNK_SLOTS;
    if (chunk < MAX_CHUNKS && !chunks[chunk])
      chunks[chunk] = calloc(CHUNK_SLOTS, sizeof(Instance));
    if (chunk >= MAX_CHUNKS || !chunks[chunk]) {
      pthread_mutex_unlock(&table_lock);
      return 0;
    }
    atomic_store(&nslot, (int)h);
  }
  fresh = slot(h);
  *fresh = *k;
  fresh->owner = d;
  fresh->instance = instance;
  fresh->in_use = 1;
  pthread_mutex_unlock(&table_lock);
  return h;
}

void free_slot(uintptr_t h) {
  pthread_mutex_lock(&table_lock);
  slot(h)->in_use = 0;
  slot(h)->owner = NULL;
  pthread_mutex_unlock(&table_lock);
}

/* The one line of why a muscle stops stepping, as a MuJoCo warning (once per cause). */
static void refuse(Instance* k, double* s, const char* err) {
  if (!k->refused) mju_warning("%s", err);
  k->refused = 1;
  set_status(s, WPAM_STATUS_MODEL);
}

/* d's own Instance of `instance`. A pickled copy holds another data's handle: it finds the
   Instance its own init made, or makes one. NULL (status set) if it cannot. */
static Instance* own_instance(const mjModel* m, mjData* d, int instance, double* s) {
  Instance* k = slot(d->plugin_data[instance]);
  Instance fresh;
  char err[600];
  uintptr_t h;
  if (owned(k, d, instance)) return k;
  h = find_owned(d, instance);
  if (!h) {
    if (derive_for_model(m, instance, &fresh, err, sizeof(err))) {
      if (!((int)s[S_STATUS] & WPAM_STATUS_MODEL)) mju_warning("%s", err);
      set_status(s, WPAM_STATUS_MODEL);
      return NULL;
    }
    h = new_slot(d, instance, &fresh);
    if (!h) return NULL;
  }
  d->plugin_data[instance] = h;
  return slot(h);
}

/* Whether k is current for model m and its options: the same model with its time step or
   integrator edited after compile (MuJoCo's viewer allows it), or without the muscle's
   friction row (no_friction_row), is refused; another model of the same state layout
   (mujoco.batch's set_models) is derived afresh. */
static int current_for(const mjModel* m, int instance, Instance* k, double* s) {
  static const char* const INTEGRATORS[] = {WPAM_INTEGRATORS};
  const int nintegrator = (int)(sizeof(INTEGRATORS) / sizeof(INTEGRATORS[0]));
  int integrator = m->opt.integrator;
  Instance fresh;
  char err[600];
  int options = k->dt == m->opt.timestep && k->integrator == integrator;
  if (k->model == m && options && !no_friction_row(m, instance, k->tendon, 1, err,
                                                   sizeof(err))) {
    k->refused = 0; /* (changed back: the muscle steps again after mj_resetData) */
    return 1;
  }
  if (k->model == m && options) { /* err: why the friction row is missing */
    refuse(k, s, err);
    return 0;
  }
  if (k->model == m) {
    snprintf(err, sizeof(err), "wpam_mj.muscle instance '%s': the %s changed after the model "
             "compiled (timestep %.6g s, integrator %s); the muscle stops until it is changed "
             "back or the model recompiled", instance_name(m, instance),
             k->dt != m->opt.timestep ? "timestep" : "integrator", m->opt.timestep,
             integrator >= 0 && integrator < nintegrator ? INTEGRATORS[integrator] : "unknown");
    refuse(k, s, err);
    return 0;
  }
  if (derive_for_model(m, instance, &fresh, err, sizeof(err))) {
    refuse(k, s, err);
    return 0;
  }
  fresh.owner = k->owner;
  fresh.instance = k->instance;
  fresh.in_use = 1;
  *k = fresh;
  return 1;
}

/* d's Instance of `instance`, current for model m; NULL when the muscle cannot step. */
Instance* instance_of(const mjModel* m, mjData* d, int instance, double* s) {
  Instance* k = own_instance(m, d, instance, s);
  return k && current_for(m, instance, k, s) ? k : NULL;
}
