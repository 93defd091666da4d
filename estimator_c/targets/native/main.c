/* Native target: the board service as a host program (board glue for POSIX).
 *
 *   estimator_native            speak the protocol on stdin/stdout
 *   estimator_native --pty      open a pseudo-terminal, print "PTY <path>" on stdout,
 *                               speak the protocol on it (a serial port to pyserial)
 *
 * Costs are measured in nanoseconds (CLOCK_MONOTONIC). Exits at end of input or
 * when the pty's other side closes. */
#define _DEFAULT_SOURCE
#define _XOPEN_SOURCE 600
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "service.h"

static int out_fd = STDOUT_FILENO;

static void write_all(const uint8_t *data, size_t n)
{
    while (n > 0) {
        const ssize_t w = write(out_fd, data, n);
        if (w <= 0) exit(0); /* the host went away */
        data += w;
        n -= (size_t)w;
    }
}

static uint32_t now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint32_t)((uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec);
}

static int open_pty(void)
{
    const int fd = posix_openpt(O_RDWR | O_NOCTTY);
    if (fd < 0 || grantpt(fd) || unlockpt(fd)) return -1;
    struct termios tio;
    if (tcgetattr(fd, &tio) == 0) {
        cfmakeraw(&tio);
        tcsetattr(fd, TCSANOW, &tio);
    }
    printf("PTY %s\n", ptsname(fd));
    fflush(stdout);
    return fd;
}

int main(int argc, char **argv)
{
    int in_fd = STDIN_FILENO;
    if (argc > 1 && strcmp(argv[1], "--pty") == 0) {
        in_fd = out_fd = open_pty();
        if (in_fd < 0) {
            perror("pty");
            return 1;
        }
    } else if (argc > 1) {
        fprintf(stderr, "usage: %s [--pty]\n", argv[0]);
        return 2;
    }
    static service_t service;
    const service_io_t io = {.write = write_all, .clock = now_ns, .timer_unit = PROTO_UNIT_NANOSECONDS,
                             .timer_hz = 1000000000u};
    service_init(&service, &io);
    service_boot(&service);
    uint8_t buf[512];
    for (;;) {
        const ssize_t n = read(in_fd, buf, sizeof buf);
        if (n <= 0) return 0;
        service_feed(&service, buf, (size_t)n);
    }
}
