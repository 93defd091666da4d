/* Native target: the board service as a host program (board glue for POSIX).
 *
 *   estimator_native            speak the protocol on stdin/stdout
 *   estimator_native --pty      open a pseudo-terminal, print "PTY <path>" on stdout,
 *                               speak the protocol on it (a serial port to pyserial)
 *   estimator_native --udp PORT listen on UDP 127.0.0.1:PORT (0: any free port), print
 *                               "UDP <port>"; one CRTP packet per datagram, as cflib's
 *                               udp:// link driver sends them: protocol messages ride on
 *                               the app channel (port 13, channel 2) without framing, and
 *                               the null packet (0xFF) is echoed so cflib's scan finds us
 *
 * Costs are measured in nanoseconds (CLOCK_MONOTONIC). Exits at end of input or
 * when the pty's other side closes. */
#define _DEFAULT_SOURCE
#define _XOPEN_SOURCE 600
#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "service.h"

#define CRTP_APP_PORT 13
#define CRTP_APP_CHANNEL 2
#define CRTP_NULL 0xFFu
#define CRTP_HEADER(port, channel) (uint8_t)(((port) << 4) | (3u << 2) | (channel))

static int out_fd = STDOUT_FILENO;

/* The UDP peer (the last address a datagram came from): answers go there. */
static struct {
    int fd;
    struct sockaddr_in peer;
    socklen_t peer_len;
} udp = {.fd = -1};

static void write_all(const uint8_t *data, size_t n)
{
    while (n > 0) {
        const ssize_t w = write(out_fd, data, n);
        if (w <= 0) exit(0); /* the host went away */
        data += w;
        n -= (size_t)w;
    }
}

/* What the service says while it handles one read's worth of input, written in one
 * system call after it: the host then wakes once a window, not once a frame. */
#define OUTPUT_BYTES 4096

typedef struct {
    uint8_t data[OUTPUT_BYTES];
    size_t n;
} output_t;

static output_t output;

static void flush_output(void)
{
    write_all(output.data, output.n);
    output.n = 0;
}

static void write_buffered(const uint8_t *data, size_t n)
{
    if (output.n + n > sizeof output.data) flush_output();
    if (n > sizeof output.data) {
        write_all(data, n);
        return;
    }
    memcpy(&output.data[output.n], data, n);
    output.n += n;
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

static void send_datagram(const uint8_t *data, size_t n)
{
    if (udp.peer_len) sendto(udp.fd, data, n, 0, (const struct sockaddr *)&udp.peer, udp.peer_len);
}

static void send_app_packet(const uint8_t *payload, size_t n)
{
    uint8_t packet[1 + PROTO_MAX_PAYLOAD];
    if (n > PROTO_MAX_PAYLOAD) return;
    packet[0] = CRTP_HEADER(CRTP_APP_PORT, CRTP_APP_CHANNEL);
    memcpy(&packet[1], payload, n);
    send_datagram(packet, n + 1);
}

static int open_udp(const char *port_arg)
{
    char *end;
    const long port = strtol(port_arg, &end, 10);
    if (*end || port < 0 || port > 65535) return -1;
    udp.fd = socket(AF_INET, SOCK_DGRAM, 0);
    struct sockaddr_in addr = {.sin_family = AF_INET, .sin_port = htons((uint16_t)port)};
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    socklen_t len = sizeof addr;
    if (udp.fd < 0 || bind(udp.fd, (struct sockaddr *)&addr, sizeof addr)
        || getsockname(udp.fd, (struct sockaddr *)&addr, &len))
        return -1;
    printf("UDP %u\n", ntohs(addr.sin_port));
    fflush(stdout);
    return 0;
}

/* One CRTP packet per datagram: the app channel carries protocol messages; others are ignored. */
static int serve_udp(service_t *service)
{
    uint8_t packet[64];
    for (;;) {
        udp.peer_len = sizeof udp.peer;
        const ssize_t n = recvfrom(udp.fd, packet, sizeof packet, 0, (struct sockaddr *)&udp.peer, &udp.peer_len);
        if (n <= 0) return 0;
        const uint8_t port = packet[0] >> 4, channel = packet[0] & 3u;
        if (packet[0] == CRTP_NULL) {
            send_datagram(packet, 1);
        } else if (port == CRTP_APP_PORT && channel == CRTP_APP_CHANNEL) {
            service_feed_packet(service, &packet[1], (size_t)n - 1);
        }
    }
}

static int serve_stream(service_t *service, int in_fd)
{
    uint8_t buf[512];
    for (;;) {
        const ssize_t n = read(in_fd, buf, sizeof buf);
        if (n <= 0) return 0;
        service_feed(service, buf, (size_t)n);
        flush_output();
    }
}

int main(int argc, char **argv)
{
    int in_fd = STDIN_FILENO;
    service_io_t io = {.write = write_buffered, .clock = now_ns, .timer_unit = PROTO_UNIT_NANOSECONDS,
                       .timer_hz = 1000000000u};
    if (argc == 2 && strcmp(argv[1], "--pty") == 0) {
        in_fd = out_fd = open_pty();
        if (in_fd < 0) {
            perror("pty");
            return 1;
        }
    } else if (argc == 3 && strcmp(argv[1], "--udp") == 0) {
        if (open_udp(argv[2])) {
            perror("udp");
            return 1;
        }
        io.packet = send_app_packet;
    } else if (argc > 1) {
        fprintf(stderr, "usage: %s [--pty | --udp PORT]\n", argv[0]);
        return 2;
    }
    static service_t service;
    service_init(&service, &io);
    service_boot(&service);
    flush_output();
    return udp.fd >= 0 ? serve_udp(&service) : serve_stream(&service, in_fd);
}
