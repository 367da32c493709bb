/* Compiled against the official FMI 2.0 headers shipped with fmpy and linked against
 * libkneebench_fmu.so. Assigning every exported symbol to the header's function-pointer typedef
 * makes the compiler check each prototype (-Werror), and the link fails if a symbol is missing.
 * It then prints the layout of the C types (compared with the Rust declarations by the test)
 * and runs GaitReference through the pointers. Usage: abi_check GUID */
#include <stddef.h>
#include <stdio.h>
#include <stdarg.h>
#include <string.h>
#include "fmi2Functions.h"

static fmi2GetTypesPlatformTYPE *pGetTypesPlatform = fmi2GetTypesPlatform;
static fmi2GetVersionTYPE *pGetVersion = fmi2GetVersion;
static fmi2SetDebugLoggingTYPE *pSetDebugLogging = fmi2SetDebugLogging;
static fmi2InstantiateTYPE *pInstantiate = fmi2Instantiate;
static fmi2FreeInstanceTYPE *pFreeInstance = fmi2FreeInstance;
static fmi2SetupExperimentTYPE *pSetupExperiment = fmi2SetupExperiment;
static fmi2EnterInitializationModeTYPE *pEnterInitializationMode = fmi2EnterInitializationMode;
static fmi2ExitInitializationModeTYPE *pExitInitializationMode = fmi2ExitInitializationMode;
static fmi2TerminateTYPE *pTerminate = fmi2Terminate;
static fmi2ResetTYPE *pReset = fmi2Reset;
static fmi2GetRealTYPE *pGetReal = fmi2GetReal;
static fmi2GetIntegerTYPE *pGetInteger = fmi2GetInteger;
static fmi2GetBooleanTYPE *pGetBoolean = fmi2GetBoolean;
static fmi2GetStringTYPE *pGetString = fmi2GetString;
static fmi2SetRealTYPE *pSetReal = fmi2SetReal;
static fmi2SetIntegerTYPE *pSetInteger = fmi2SetInteger;
static fmi2SetBooleanTYPE *pSetBoolean = fmi2SetBoolean;
static fmi2SetStringTYPE *pSetString = fmi2SetString;
static fmi2GetFMUstateTYPE *pGetFMUstate = fmi2GetFMUstate;
static fmi2SetFMUstateTYPE *pSetFMUstate = fmi2SetFMUstate;
static fmi2FreeFMUstateTYPE *pFreeFMUstate = fmi2FreeFMUstate;
static fmi2SerializedFMUstateSizeTYPE *pSerializedFMUstateSize = fmi2SerializedFMUstateSize;
static fmi2SerializeFMUstateTYPE *pSerializeFMUstate = fmi2SerializeFMUstate;
static fmi2DeSerializeFMUstateTYPE *pDeSerializeFMUstate = fmi2DeSerializeFMUstate;
static fmi2GetDirectionalDerivativeTYPE *pGetDirectionalDerivative = fmi2GetDirectionalDerivative;
static fmi2SetRealInputDerivativesTYPE *pSetRealInputDerivatives = fmi2SetRealInputDerivatives;
static fmi2GetRealOutputDerivativesTYPE *pGetRealOutputDerivatives = fmi2GetRealOutputDerivatives;
static fmi2DoStepTYPE *pDoStep = fmi2DoStep;
static fmi2CancelStepTYPE *pCancelStep = fmi2CancelStep;
static fmi2GetStatusTYPE *pGetStatus = fmi2GetStatus;
static fmi2GetRealStatusTYPE *pGetRealStatus = fmi2GetRealStatus;
static fmi2GetIntegerStatusTYPE *pGetIntegerStatus = fmi2GetIntegerStatus;
static fmi2GetBooleanStatusTYPE *pGetBooleanStatus = fmi2GetBooleanStatus;
static fmi2GetStringStatusTYPE *pGetStringStatus = fmi2GetStringStatus;

static int messages = 0;
static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                   fmi2String category, fmi2String message, ...) {
    char buf[2048];
    va_list ap;
    va_start(ap, message);
    vsnprintf(buf, sizeof buf, message, ap);
    va_end(ap);
    if (env != (void *)&messages) printf("bad-environment\n");
    messages++;
    printf("log %d %s %s\n", (int)status, category, buf);
}

#define P(name, expr) printf("%s %zu\n", name, (size_t)(expr))

int main(int argc, char **argv) {
    if (argc < 2) return 2;
    P("sizeof_fmi2Boolean", sizeof(fmi2Boolean));
    P("sizeof_fmi2Integer", sizeof(fmi2Integer));
    P("sizeof_fmi2Real", sizeof(fmi2Real));
    P("sizeof_fmi2ValueReference", sizeof(fmi2ValueReference));
    P("sizeof_fmi2Status", sizeof(fmi2Status));
    P("sizeof_fmi2Type", sizeof(fmi2Type));
    P("sizeof_fmi2StatusKind", sizeof(fmi2StatusKind));
    P("sizeof_fmi2Byte", sizeof(fmi2Byte));
    P("sizeof_fmi2CallbackFunctions", sizeof(fmi2CallbackFunctions));
    P("offsetof_logger", offsetof(fmi2CallbackFunctions, logger));
    P("offsetof_allocateMemory", offsetof(fmi2CallbackFunctions, allocateMemory));
    P("offsetof_freeMemory", offsetof(fmi2CallbackFunctions, freeMemory));
    P("offsetof_stepFinished", offsetof(fmi2CallbackFunctions, stepFinished));
    P("offsetof_componentEnvironment", offsetof(fmi2CallbackFunctions, componentEnvironment));
    P("sizeof_fmi2EventInfo", sizeof(fmi2EventInfo));
    P("offsetof_nextEventTime", offsetof(fmi2EventInfo, nextEventTime));
    P("value_fmi2OK", fmi2OK);
    P("value_fmi2Pending", fmi2Pending);
    P("value_fmi2CoSimulation", fmi2CoSimulation);
    P("value_fmi2Terminated", fmi2Terminated);
    P("value_fmi2LastSuccessfulTime", fmi2LastSuccessfulTime);
    printf("platform %s\n", pGetTypesPlatform());
    printf("version %s\n", pGetVersion());

    fmi2CallbackFunctions cb = {logger, NULL, NULL, NULL, &messages};
    fmi2Component c = pInstantiate("abi", fmi2CoSimulation, argv[1], "file:///tmp", &cb,
                                   fmi2False, fmi2False);
    if (!c) { printf("instantiate-failed\n"); return 1; }
    /* A call out of sequence must be refused, with a log line. */
    printf("early_doStep %d\n", (int)pDoStep(c, 0.0, 0.1, fmi2True));
    printf("setup %d\n", (int)pSetupExperiment(c, fmi2False, 0.0, 0.0, fmi2True, 10.0));
    printf("enter %d\n", (int)pEnterInitializationMode(c));
    printf("exit %d\n", (int)pExitInitializationMode(c));
    fmi2ValueReference vrs[4] = {100, 101, 102, 104};
    fmi2Real v[4];
    double t = 0.0, h = 0.001;
    for (int i = 0; i < 2500; i++) {
        if (pDoStep(c, t, h, fmi2True) != fmi2OK) { printf("step-failed %d\n", i); return 1; }
        t = (i + 1) * h;
    }
    pGetReal(c, vrs, 4, v);
    printf("values %.17g %.17g %.17g %.17g\n", v[0], v[1], v[2], v[3]);
    fmi2Integer order[1] = {1};
    fmi2Real d[1];
    int derivative_status = (int)pGetRealOutputDerivatives(c, vrs, 1, order, d);
    printf("derivative_status %d\n", derivative_status);
    printf("derivative %.17g\n", d[0]);
    fmi2Boolean terminated = 1;
    int terminated_status = (int)pGetBooleanStatus(c, fmi2Terminated, &terminated);
    printf("terminated_status %d %d\n", terminated_status, terminated);
    fmi2Real last = -1;
    int last_status = (int)pGetRealStatus(c, fmi2LastSuccessfulTime, &last);
    printf("last_status %d %.17g\n", last_status, last);
    fmi2Status st;
    printf("dostep_status_kind %d\n", (int)pGetStatus(c, fmi2DoStepStatus, &st));
    printf("directional %d\n", (int)pGetDirectionalDerivative(c, NULL, 0, NULL, 0, NULL, NULL));
    printf("terminate %d\n", (int)pTerminate(c));
    pFreeInstance(c);
    printf("messages %d\n", messages);
    /* Reference the remaining pointers so none is optimised away unchecked. */
    void *all[] = {(void *)pSetDebugLogging, (void *)pReset, (void *)pGetInteger,
                   (void *)pGetString, (void *)pSetReal, (void *)pSetInteger, (void *)pSetBoolean,
                   (void *)pSetString, (void *)pGetFMUstate, (void *)pSetFMUstate,
                   (void *)pFreeFMUstate, (void *)pSerializedFMUstateSize,
                   (void *)pSerializeFMUstate, (void *)pDeSerializeFMUstate,
                   (void *)pSetRealInputDerivatives, (void *)pCancelStep,
                   (void *)pGetIntegerStatus, (void *)pGetStringStatus, (void *)pGetBoolean};
    for (size_t i = 0; i < sizeof all / sizeof all[0]; i++)
        if (!all[i]) { printf("null-pointer %zu\n", i); return 1; }
    printf("done 1\n");
    return 0;
}
