/*
 * A tiny FMI 2.0 co-simulation FMU for the harness tests (modelIdentifier "kbtest").
 *
 * Real:    u (input, vr 0), y = k*u + b (output, vr 1, direct feedthrough), k (parameter, vr 2),
 *          b (parameter, vr 3), x (output, vr 4: x += u at every step), t (output, vr 5: the
 *          FMU's time), discard_at (parameter, vr 6), error_at (parameter, vr 7)
 * Integer: steps (output, vr 0: number of doStep calls), i_in (input, vr 1),
 *          i_out = 2 * i_in (output, vr 2)
 * Boolean: b_in (input, vr 0), b_out = !b_in (output, vr 1)
 *
 * discard_at >= 0: the step that would pass it integrates up to discard_at (x += u times the
 *   fraction of the step), returns fmi2Discard and terminates there: fmi2LastSuccessfulTime
 *   and the output t are discard_at.
 * error_at >= 0: the step that would pass it returns fmi2Error with a log message.
 */
#include <stdlib.h>
#include <string.h>

/* The official FMI 2.0 headers (vendored with the hostile FMU: harness/tests/hostile_fmu/fmi2/,
 * BSD 2-clause, Modelica Association): every function below is checked against its declared
 * type, and exported (FMI2_Export sets default visibility; the library is built with
 * -fvisibility=hidden). */
#include "fmi2Functions.h"

#ifndef KBTEST_GUID
#define KBTEST_GUID "{kbtest-0001}"
#endif

typedef struct {
    double r[8];
    int i[3];
    int b[2];
    int terminated;
    double last_time;
} State;

typedef struct {
    State s;
    fmi2CallbackFunctions cb;
    char name[128];
} Inst;

static void compute(State *s) {
    s->r[1] = s->r[2] * s->r[0] + s->r[3];
    s->i[2] = 2 * s->i[1];
    s->b[1] = !s->b[0];
}

#define LOG(c, st, ...) do { if ((c)->cb.logger) (c)->cb.logger((c)->cb.componentEnvironment, (c)->name, st, "log", __VA_ARGS__); } while (0)

const char *fmi2GetTypesPlatform(void) { return "default"; }
const char *fmi2GetVersion(void) { return "2.0"; }
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cat[]) { (void)c; (void)on; (void)n; (void)cat; return fmi2OK; }

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String res,
                                     const fmi2CallbackFunctions *cb, fmi2Boolean visible, fmi2Boolean logging) {
    (void)visible; (void)logging;
    if (!cb || !name) return NULL;
    if (type != fmi2CoSimulation) return NULL;
    if (!guid || strcmp(guid, KBTEST_GUID) != 0) {
        if (cb->logger) cb->logger(cb->componentEnvironment, name, fmi2Error, "error",
                                   "GUID mismatch: the binary expects %s but got %s", KBTEST_GUID, guid ? guid : "(null)");
        return NULL;
    }
    if (!res || strncmp(res, "file://", 7) != 0) {
        if (cb->logger) cb->logger(cb->componentEnvironment, name, fmi2Error, "error", "bad resource location %s", res ? res : "(null)");
        return NULL;
    }
    Inst *c = calloc(1, sizeof(Inst));
    if (!c) return NULL;
    c->cb = *cb;
    strncpy(c->name, name, sizeof c->name - 1);
    c->s.r[2] = 1.0;
    c->s.r[6] = -1.0;
    c->s.r[7] = -1.0;
    compute(&c->s);
    LOG(c, fmi2OK, "instantiated %s with resources at %s", name, res);
    return c;
}

void fmi2FreeInstance(fmi2Component c) { free(c); }
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDef, fmi2Real tol, fmi2Real start, fmi2Boolean stopDef, fmi2Real stop) {
    (void)tolDef; (void)tol; (void)stopDef; (void)stop;
    ((Inst *)c)->s.r[5] = start;
    return fmi2OK;
}
fmi2Status fmi2EnterInitializationMode(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) { compute(&((Inst *)c)->s); return fmi2OK; }
fmi2Status fmi2Terminate(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) { Inst *i = c; memset(&i->s, 0, sizeof i->s); i->s.r[2] = 1; i->s.r[6] = -1; i->s.r[7] = -1; compute(&i->s); return fmi2OK; }

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    Inst *i = c; compute(&i->s);
    for (size_t k = 0; k < n; k++) { if (vr[k] > 7) return fmi2Error; v[k] = i->s.r[vr[k]]; }
    return fmi2OK;
}
fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]) {
    Inst *i = c; compute(&i->s);
    for (size_t k = 0; k < n; k++) { if (vr[k] > 2) return fmi2Error; v[k] = i->s.i[vr[k]]; }
    return fmi2OK;
}
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]) {
    Inst *i = c; compute(&i->s);
    for (size_t k = 0; k < n; k++) { if (vr[k] > 1) return fmi2Error; v[k] = i->s.b[vr[k]]; }
    return fmi2OK;
}
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]) { (void)c; (void)vr; (void)v; return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    Inst *i = c;
    for (size_t k = 0; k < n; k++) { if (vr[k] > 7) return fmi2Error; i->s.r[vr[k]] = v[k]; }
    return fmi2OK;
}
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]) {
    Inst *i = c;
    for (size_t k = 0; k < n; k++) { if (vr[k] > 2) return fmi2Error; i->s.i[vr[k]] = v[k]; }
    return fmi2OK;
}
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]) {
    Inst *i = c;
    for (size_t k = 0; k < n; k++) { if (vr[k] > 1) return fmi2Error; i->s.b[vr[k]] = v[k]; }
    return fmi2OK;
}
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[]) { (void)c; (void)vr; (void)v; return n ? fmi2Error : fmi2OK; }

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSet) {
    Inst *i = c; State *s = &i->s; (void)noSet;
    if (s->r[6] >= 0 && t + h > s->r[6] + 1e-9) {
        /* The model ends at discard_at (or at t, if that is already past it): it integrates up
         * to there, so its outputs are those at its last successful time. */
        double end = s->r[6] > t ? s->r[6] : t;
        s->r[4] += s->r[0] * (end - t) / h;
        s->r[5] = end;
        s->terminated = 1;
        s->last_time = end;
        LOG(i, fmi2Discard, "terminating: t + h = %g passes discard_at = %g", t + h, s->r[6]);
        return fmi2Discard;
    }
    if (s->r[7] >= 0 && t + h > s->r[7] + 1e-9) {
        LOG(i, fmi2Error, "error requested: t + h = %g passes error_at = %g", t + h, s->r[7]);
        return fmi2Error;
    }
    s->r[4] += s->r[0];
    s->r[5] = t + h;
    s->i[0] += 1;
    s->last_time = t + h;
    return fmi2OK;
}
/* Declared incapable in the model description (no directional derivatives, maxOutputDerivativeOrder
 * 0, canInterpolateInputs false), exported because FMI 2.0 requires every function (fmpy loads
 * them all). KBTEST_WITHOUT_DIRECTIONAL_DERIVATIVE builds a binary that lacks one, for the test
 * of a description promising what the binary does not export. */
#ifndef KBTEST_WITHOUT_DIRECTIONAL_DERIVATIVE
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference z[], size_t nz,
                                        const fmi2Real dv[], fmi2Real dz[]) {
    (void)u; (void)nu; (void)z; (void)nz; (void)dv; (void)dz;
    LOG((Inst *)c, fmi2Error, "fmi2GetDirectionalDerivative is not provided");
    return fmi2Error;
}
#endif
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real v[]) {
    (void)vr; (void)n; (void)order; (void)v;
    LOG((Inst *)c, fmi2Error, "fmi2SetRealInputDerivatives is not provided");
    return fmi2Error;
}
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real v[]) {
    (void)vr; (void)n; (void)order; (void)v;
    LOG((Inst *)c, fmi2Error, "fmi2GetRealOutputDerivatives is not provided");
    return fmi2Error;
}
fmi2Status fmi2CancelStep(fmi2Component c) { (void)c; return fmi2Error; }
fmi2Status fmi2GetStatus(fmi2Component c, fmi2StatusKind k, fmi2Status *v) { (void)c; (void)k; (void)v; return fmi2Discard; }
fmi2Status fmi2GetRealStatus(fmi2Component c, fmi2StatusKind k, fmi2Real *v) {
    if (k != fmi2LastSuccessfulTime) return fmi2Discard;
    *v = ((Inst *)c)->s.last_time; return fmi2OK;
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, fmi2StatusKind k, fmi2Integer *v) { (void)c; (void)k; (void)v; return fmi2Discard; }
fmi2Status fmi2GetBooleanStatus(fmi2Component c, fmi2StatusKind k, fmi2Boolean *v) {
    if (k != fmi2Terminated) return fmi2Discard;
    *v = ((Inst *)c)->s.terminated; return fmi2OK;
}
fmi2Status fmi2GetStringStatus(fmi2Component c, fmi2StatusKind k, fmi2String *v) { (void)c; (void)k; (void)v; return fmi2Discard; }

/* FMU state: a copy of State; serialization: its bytes. */
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *st) {
    if (!*st) *st = malloc(sizeof(State));
    memcpy(*st, &((Inst *)c)->s, sizeof(State)); return fmi2OK;
}
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate st) { memcpy(&((Inst *)c)->s, st, sizeof(State)); return fmi2OK; }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *st) { (void)c; free(*st); *st = NULL; return fmi2OK; }
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate st, size_t *n) { (void)c; (void)st; *n = sizeof(State); return fmi2OK; }
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate st, fmi2Byte b[], size_t n) { (void)c; if (n != sizeof(State)) return fmi2Error; memcpy(b, st, n); return fmi2OK; }
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate *st) {
    (void)c; if (n != sizeof(State)) return fmi2Error;
    *st = malloc(sizeof(State)); memcpy(*st, b, n); return fmi2OK;
}
