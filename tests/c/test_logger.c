/* A variadic FMI logger for the tests (Rust cannot define C-variadic functions). It formats
 * the message with vsnprintf, exactly as an importer must, and appends one line per message to
 * the kb_log the componentEnvironment points to. */
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

typedef struct {
    char buf[1 << 16];
    size_t len;
    int count;
    void *last_environment;
} kb_log;

void kb_test_logger(void *env, const char *name, int status, const char *category,
                    const char *fmt, ...) {
    kb_log *log = (kb_log *)env;
    if (!log) return;
    char msg[4096];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    int n = snprintf(log->buf + log->len, sizeof(log->buf) - log->len, "[%d|%s|%s] %s\n",
                     status, category ? category : "", name ? name : "", msg);
    if (n > 0 && log->len + (size_t)n < sizeof(log->buf)) log->len += (size_t)n;
    log->count++;
    log->last_environment = env;
}
