/*
 * "Hostile": an FMI 2.0 co-simulation FMU (modelIdentifier "hostile") that misbehaves on
 * request, compiled against the official FMI 2.0 headers (fmi2/, BSD 2-clause, Modelica
 * Association) by the harness tests.
 *
 * Variables (value references):
 *   Real    u      (input, 0)       the input; y = 2 u
 *   Real    y      (output, 1)      2 u, or NaN / +Inf once a "nan" / "inf" behaviour fired
 *   Real    t      (output, 2)      the FMU's time (end of the last step)
 *   Real    at     (parameter, 3)   the time at which the behaviour fires: the first doStep
 *                                   whose end passes it (t + h > at)
 *   Integer mode   (parameter, 0)   the behaviour, see MODE_* below
 *   Integer steps  (output, 1)      doStep calls done
 *   Real    pace   (parameter, 4)   wall-clock seconds every doStep sleeps first (default 0), so
 *                                   that a test can let time pass before the behaviour fires
 *
 * Every behaviour first logs "hostile: <what> at t=<t>" with the status it is about to cause.
 */
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "fmi2Functions.h"

#define GUID "{kneebench-hostile-0001}"

enum {
    MODE_NONE = 0,
    MODE_SEGFAULT = 1, /* write through a NULL pointer */
    MODE_ABORT = 2,    /* abort() */
    MODE_EXIT = 3,     /* exit(0): the process ends "successfully" */
    MODE_HANG = 4,     /* an infinite loop */
    MODE_NAN = 5,      /* y becomes NaN, status fmi2OK */
    MODE_INF = 6,      /* y becomes +Inf, status fmi2OK */
    MODE_WARNING = 7,  /* the step is done, status fmi2Warning */
    MODE_DISCARD = 8,  /* fmi2Discard, terminated true, lastSuccessfulTime = the step's start */
    MODE_ERROR = 9,    /* fmi2Error */
    MODE_FATAL = 10,   /* fmi2Fatal */
    MODE_PENDING = 11, /* fmi2Pending (never allowed: the importer did not ask for async) */
    MODE_STDOUT = 12,  /* writes garbage to standard output and continues (fmi2OK) */
    MODE_EXIT_LATER = 13, /* fmi2OK, and a thread ends the process 200 ms later (_exit(7)) */
};

static void *exit_later(void *arg) {
    (void)arg;
    struct timespec ms200 = {0, 200000000L};
    nanosleep(&ms200, NULL);
    _exit(7);
    return NULL;
}

typedef struct {
    fmi2Real u, t, at, pace;
    fmi2Integer mode, steps;
    int fired;      /* the behaviour fired (NaN / Inf outputs stay) */
    int terminated; /* after MODE_DISCARD */
    fmi2Real last_time;
} State;

typedef struct {
    State s;
    fmi2CallbackFunctions cb;
    char name[128];
} Inst;

#define LOG(c, st, ...)                                                                            \
    do {                                                                                           \
        if ((c)->cb.logger)                                                                        \
            (c)->cb.logger((c)->cb.componentEnvironment, (c)->name, st, "hostile", __VA_ARGS__);   \
    } while (0)

static fmi2Real y_of(const State *s) {
    if (s->fired && s->mode == MODE_NAN) return NAN;
    if (s->fired && s->mode == MODE_INF) return INFINITY;
    return 2.0 * s->u;
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cat[]) {
    (void)c; (void)on; (void)n; (void)cat;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String res,
                              const fmi2CallbackFunctions *cb, fmi2Boolean visible,
                              fmi2Boolean logging) {
    (void)res; (void)visible; (void)logging;
    if (!cb || !name || type != fmi2CoSimulation || !guid || strcmp(guid, GUID) != 0) return NULL;
    Inst *c = calloc(1, sizeof(Inst));
    if (!c) return NULL;
    c->cb = *cb;
    strncpy(c->name, name, sizeof c->name - 1);
    c->s.at = 0.0;
    return c;
}

void fmi2FreeInstance(fmi2Component c) { free(c); }
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDef, fmi2Real tol, fmi2Real start,
                               fmi2Boolean stopDef, fmi2Real stop) {
    (void)tolDef; (void)tol; (void)stopDef; (void)stop;
    ((Inst *)c)->s.t = start;
    ((Inst *)c)->s.last_time = start;
    return fmi2OK;
}
fmi2Status fmi2EnterInitializationMode(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2Terminate(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) {
    Inst *i = c;
    memset(&i->s, 0, sizeof i->s);
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    Inst *i = c;
    for (size_t k = 0; k < n; k++) {
        switch (vr[k]) {
        case 0: v[k] = i->s.u; break;
        case 1: v[k] = y_of(&i->s); break;
        case 2: v[k] = i->s.t; break;
        case 3: v[k] = i->s.at; break;
        case 4: v[k] = i->s.pace; break;
        default: LOG(i, fmi2Error, "no Real with value reference %u", vr[k]); return fmi2Error;
        }
    }
    return fmi2OK;
}
fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                          fmi2Integer v[]) {
    Inst *i = c;
    for (size_t k = 0; k < n; k++) {
        switch (vr[k]) {
        case 0: v[k] = i->s.mode; break;
        case 1: v[k] = i->s.steps; break;
        default: LOG(i, fmi2Error, "no Integer with value reference %u", vr[k]); return fmi2Error;
        }
    }
    return fmi2OK;
}
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                          fmi2Boolean v[]) {
    (void)c; (void)vr; (void)v;
    return n ? fmi2Error : fmi2OK;
}
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]) {
    (void)c; (void)vr; (void)v;
    return n ? fmi2Error : fmi2OK;
}
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                       const fmi2Real v[]) {
    Inst *i = c;
    for (size_t k = 0; k < n; k++) {
        switch (vr[k]) {
        case 0: i->s.u = v[k]; break;
        case 3: i->s.at = v[k]; break;
        case 4:
            if (!(v[k] >= 0.0 && v[k] <= 10.0)) {
                LOG(i, fmi2Error, "pace %g is outside [0, 10] s", v[k]);
                return fmi2Error;
            }
            i->s.pace = v[k];
            break;
        default: LOG(i, fmi2Error, "cannot set Real %u", vr[k]); return fmi2Error;
        }
    }
    return fmi2OK;
}
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                          const fmi2Integer v[]) {
    Inst *i = c;
    for (size_t k = 0; k < n; k++) {
        if (vr[k] != 0) { LOG(i, fmi2Error, "cannot set Integer %u", vr[k]); return fmi2Error; }
        i->s.mode = v[k];
    }
    return fmi2OK;
}
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                          const fmi2Boolean v[]) {
    (void)c; (void)vr; (void)v;
    return n ? fmi2Error : fmi2OK;
}
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                         const fmi2String v[]) {
    (void)c; (void)vr; (void)v;
    return n ? fmi2Error : fmi2OK;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSet) {
    Inst *i = c;
    State *s = &i->s;
    (void)noSet;
    if (s->pace > 0.0) {
        struct timespec d;
        d.tv_sec = (time_t)s->pace;
        d.tv_nsec = (long)((s->pace - (double)d.tv_sec) * 1e9);
        nanosleep(&d, NULL);
    }
    if (s->terminated) {
        LOG(i, fmi2Error, "hostile: doStep after the FMU terminated");
        return fmi2Error;
    }
    if (s->mode != MODE_NONE && !s->fired && t + h > s->at + 1e-9) {
        s->fired = 1;
        switch (s->mode) {
        case MODE_SEGFAULT: {
            LOG(i, fmi2OK, "hostile: segfault at t=%g", t);
            volatile int *volatile p = NULL;
            *p = 1;
            break;
        }
        case MODE_ABORT:
            LOG(i, fmi2OK, "hostile: abort at t=%g", t);
            abort();
        case MODE_EXIT:
            LOG(i, fmi2OK, "hostile: exit(0) at t=%g", t);
            exit(0);
        case MODE_HANG: {
            LOG(i, fmi2OK, "hostile: hang at t=%g", t);
            volatile int spin = 1;
            while (spin) {
            }
            break;
        }
        case MODE_NAN: LOG(i, fmi2OK, "hostile: NaN output from t=%g", t); break;
        case MODE_INF: LOG(i, fmi2OK, "hostile: Inf output from t=%g", t); break;
        case MODE_WARNING:
            s->t = t + h;
            s->steps += 1;
            s->last_time = t + h;
            LOG(i, fmi2Warning, "hostile: warning at t=%g", t);
            return fmi2Warning;
        case MODE_DISCARD:
            s->terminated = 1;
            s->last_time = t;
            LOG(i, fmi2Discard, "hostile: discard at t=%g", t);
            return fmi2Discard;
        case MODE_ERROR:
            LOG(i, fmi2Error, "hostile: error at t=%g", t);
            return fmi2Error;
        case MODE_FATAL:
            LOG(i, fmi2Fatal, "hostile: fatal at t=%g", t);
            return fmi2Fatal;
        case MODE_PENDING:
            LOG(i, fmi2Pending, "hostile: pending at t=%g", t);
            return fmi2Pending;
        case MODE_STDOUT:
            LOG(i, fmi2OK, "hostile: garbage on stdout at t=%g", t);
            fputs("hostile garbage on stdout\n", stdout);
            fflush(stdout);
            (void)!write(1, "\x01\x02\x03garbage", 10);
            break;
        case MODE_EXIT_LATER: {
            LOG(i, fmi2OK, "hostile: the process ends in 200 ms, from t=%g", t);
            pthread_t thread;
            if (pthread_create(&thread, NULL, exit_later, NULL) != 0) return fmi2Error;
            pthread_detach(thread);
            break;
        }
        default:
            LOG(i, fmi2Error, "hostile: unknown mode %d", s->mode);
            return fmi2Error;
        }
    }
    s->t = t + h;
    s->steps += 1;
    s->last_time = t + h;
    return fmi2OK;
}
fmi2Status fmi2CancelStep(fmi2Component c) { (void)c; return fmi2Error; }
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind k, fmi2Status *v) {
    (void)c; (void)k; (void)v;
    return fmi2Discard;
}
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind k, fmi2Real *v) {
    if (k != fmi2LastSuccessfulTime) return fmi2Discard;
    *v = ((Inst *)c)->s.last_time;
    return fmi2OK;
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind k, fmi2Integer *v) {
    (void)c; (void)k; (void)v;
    return fmi2Discard;
}
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind k, fmi2Boolean *v) {
    if (k != fmi2Terminated) return fmi2Discard;
    *v = ((Inst *)c)->s.terminated;
    return fmi2OK;
}
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind k, fmi2String *v) {
    (void)c; (void)k; (void)v;
    return fmi2Discard;
}
