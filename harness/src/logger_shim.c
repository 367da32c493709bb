/*
 * The FMI 2.0 logger callback is printf-style and variadic, which Rust cannot define.
 * This shim formats the message with vsnprintf (growing the buffer as needed) and hands the
 * finished string to the Rust sink `kneebench_log_sink`, which never unwinds.
 */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>

typedef void *fmi2ComponentEnvironment;
typedef const char *fmi2String;

extern void kneebench_log_sink(fmi2ComponentEnvironment env, fmi2String instanceName, int status,
                               fmi2String category, fmi2String formatted);

void kneebench_logger(fmi2ComponentEnvironment env, fmi2String instanceName, int status,
                      fmi2String category, fmi2String message, ...) {
    char stack_buf[1024];
    char *buf = stack_buf;
    size_t cap = sizeof stack_buf;
    va_list args;
    int n;

    if (message == NULL) {
        kneebench_log_sink(env, instanceName, status, category, "(null message)");
        return;
    }

    va_start(args, message);
    n = vsnprintf(buf, cap, message, args);
    va_end(args);

    if (n < 0) {
        kneebench_log_sink(env, instanceName, status, category, message);
        return;
    }
    if ((size_t)n >= cap) {
        cap = (size_t)n + 1;
        buf = (char *)malloc(cap);
        if (buf == NULL) {
            kneebench_log_sink(env, instanceName, status, category, message);
            return;
        }
        va_start(args, message);
        vsnprintf(buf, cap, message, args);
        va_end(args);
    }

    kneebench_log_sink(env, instanceName, status, category, buf);

    if (buf != stack_buf) {
        free(buf);
    }
}
