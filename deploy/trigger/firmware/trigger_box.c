/*
 * contourcap trigger box — reference firmware for protocol v1 (see ../PROTOCOL.md).
 *
 * Target: Raspberry Pi Pico (RP2040), Pico SDK >= 1.5 with its bundled TinyUSB.
 * This is a REFERENCE SKETCH: it documents the device side of the protocol the
 * driver (capture/trigger.py) speaks and that tests/test_trigger.py simulates.
 * It is not built by the project's CI (no ARM toolchain there).
 *
 * Build outline (CMakeLists.txt next to this file):
 *   add_executable(trigger_box trigger_box.c)
 *   target_include_directories(trigger_box PRIVATE ${CMAKE_CURRENT_LIST_DIR})  # tusb_config.h
 *   target_link_libraries(trigger_box pico_stdlib pico_unique_id tinyusb_device tinyusb_board)
 *   pico_add_extra_outputs(trigger_box)
 * tusb_config.h: CFG_TUSB_RHPORT0_MODE OPT_MODE_DEVICE, CFG_TUD_ENDPOINT0_SIZE 64,
 *   all class drivers 0 (vendor *control* requests reach tud_vendor_control_xfer_cb
 *   without the vendor class driver).
 *
 * Outputs: GPIO 2..5 drive the camera trigger inputs (3.3 V; use a 74HCT245 or
 * optocouplers for 5 V / isolated inputs).  All outputs rise together.
 */

#include <string.h>

#include "hardware/gpio.h"
#include "hardware/sync.h"
#include "pico/stdlib.h"
#include "pico/unique_id.h"
#include "tusb.h"

#define VID 0x1209
#define PID 0x0001 /* pid.codes test PID: get your own for distributed hardware */
#define PROTOCOL_VERSION 1
#define FW_MAJOR 1
#define FW_MINOR 0
#define N_OUTPUTS 4
#define FIRST_PIN 2
#define OUT_MASK (((1u << N_OUTPUTS) - 1u) << FIRST_PIN)

enum { REQ_INFO = 0x01, REQ_RATE = 0x02, REQ_START = 0x03, REQ_STOP = 0x04,
       REQ_ARM = 0x05, REQ_COUNTER = 0x06, REQ_TIME = 0x07 };
enum { FLAG_RUNNING = 1u, FLAG_ARMED = 2u };

/* ---- pulse generator ---------------------------------------------------- */

static volatile uint32_t period_us = 33333, width_us = 1000;
static volatile uint32_t count;          /* pulses since START/ARM */
static volatile uint32_t limit;          /* 0 = free-running */
static volatile bool running;
static volatile uint64_t last_pulse_us;  /* time_us_64() at the last rising edge */
static repeating_timer_t pulse_timer;

static int64_t fall_cb(alarm_id_t id, void *user) {
    (void)id; (void)user;
    gpio_clr_mask(OUT_MASK);
    return 0; /* one-shot */
}

static bool rise_cb(repeating_timer_t *t) {
    (void)t;
    if (!running) return false;
    gpio_set_mask(OUT_MASK);
    last_pulse_us = time_us_64();
    count++;
    add_alarm_in_us(width_us, fall_cb, NULL, true);
    if (limit && count >= limit) { running = false; return false; }
    return true;
}

static void start_pulses(uint32_t n_pulses) {
    cancel_repeating_timer(&pulse_timer);
    uint32_t irq = save_and_disable_interrupts();
    count = 0; limit = n_pulses; running = true;
    restore_interrupts(irq);
    rise_cb(&pulse_timer);  /* first rising edge now */
    /* negative delay = period between rising edges, independent of callback time */
    if (running) add_repeating_timer_us(-(int64_t)period_us, rise_cb, NULL, &pulse_timer);
}

static void stop_pulses(void) {
    running = false;
    cancel_repeating_timer(&pulse_timer);
}

/* ---- little-endian packing --------------------------------------------- */

static void put_u32(uint8_t *p, uint32_t v) { for (int i = 0; i < 4; i++) p[i] = (uint8_t)(v >> (8 * i)); }
static void put_u64(uint8_t *p, uint64_t v) { for (int i = 0; i < 8; i++) p[i] = (uint8_t)(v >> (8 * i)); }
static uint32_t get_u32(const uint8_t *p) { return p[0] | (p[1] << 8) | (p[2] << 16) | ((uint32_t)p[3] << 24); }

/* ---- vendor control requests ------------------------------------------- */

static uint8_t reply[16];
static uint8_t payload[8];

bool tud_vendor_control_xfer_cb(uint8_t rhport, uint8_t stage, tusb_control_request_t const *req) {
    if (req->bmRequestType_bit.type != TUSB_REQ_TYPE_VENDOR ||
        req->bmRequestType_bit.recipient != TUSB_REQ_RCPT_DEVICE) return false; /* STALL */
    bool in = req->bmRequestType_bit.direction == TUSB_DIR_IN;

    if (stage == CONTROL_STAGE_SETUP) {
        if (in) {
            uint16_t len;
            switch (req->bRequest) {
            case REQ_INFO:
                memcpy(reply, "CCTB", 4);
                reply[4] = PROTOCOL_VERSION; reply[5] = FW_MAJOR; reply[6] = FW_MINOR; reply[7] = N_OUTPUTS;
                len = 8; break;
            case REQ_COUNTER: {
                uint32_t irq = save_and_disable_interrupts();
                uint32_t c = count; uint64_t last = last_pulse_us; bool run = running; uint32_t lim = limit;
                restore_interrupts(irq);
                put_u32(reply, c);
                put_u32(reply + 4, (run ? FLAG_RUNNING : 0) | (run && lim ? FLAG_ARMED : 0));
                put_u64(reply + 8, last);
                len = 16; break;
            }
            case REQ_TIME: put_u64(reply, time_us_64()); len = 8; break;
            default: return false;
            }
            if (req->wLength != len) return false;
            return tud_control_xfer(rhport, req, reply, len);
        }
        switch (req->bRequest) {  /* OUT: check length, then receive the data stage */
        case REQ_RATE: if (req->wLength != 8) return false; break;
        case REQ_ARM: if (req->wLength != 4) return false; break;
        case REQ_START: case REQ_STOP: if (req->wLength != 0) return false; break;
        default: return false;
        }
        return tud_control_xfer(rhport, req, payload, req->wLength);
    }

    if (stage == CONTROL_STAGE_DATA && !in) {  /* OUT data received: act */
        switch (req->bRequest) {
        case REQ_RATE: {
            uint32_t p = get_u32(payload), w = get_u32(payload + 4);
            if (p < 1000 || w < 1 || w >= p) return false;
            period_us = p; width_us = w;
            if (running) { uint32_t left = limit ? limit - count : 0; start_pulses(left); }
            break;
        }
        case REQ_ARM: {
            uint32_t n = get_u32(payload);
            if (n == 0) return false;
            start_pulses(n);
            break;
        }
        default: break;
        }
        return true;
    }
    if (stage == CONTROL_STAGE_ACK && !in && req->wLength == 0) {  /* no-data OUT requests */
        if (req->bRequest == REQ_START) start_pulses(0);
        else if (req->bRequest == REQ_STOP) stop_pulses();
    }
    return true;
}

/* ---- descriptors --------------------------------------------------------- */

static tusb_desc_device_t const desc_device = {
    .bLength = sizeof(tusb_desc_device_t), .bDescriptorType = TUSB_DESC_DEVICE, .bcdUSB = 0x0200,
    .bDeviceClass = TUSB_CLASS_VENDOR_SPECIFIC, .bDeviceSubClass = 0, .bDeviceProtocol = 0,
    .bMaxPacketSize0 = CFG_TUD_ENDPOINT0_SIZE, .idVendor = VID, .idProduct = PID, .bcdDevice = 0x0100,
    .iManufacturer = 1, .iProduct = 2, .iSerialNumber = 3, .bNumConfigurations = 1,
};

#define CONFIG_LEN (TUD_CONFIG_DESC_LEN + 9)
static uint8_t const desc_config[] = {
    TUD_CONFIG_DESCRIPTOR(1, 1, 0, CONFIG_LEN, 0x80, 100),
    /* one vendor interface without endpoints: everything goes over EP0 */
    9, TUSB_DESC_INTERFACE, 0, 0, 0, TUSB_CLASS_VENDOR_SPECIFIC, 0, 0, 0,
};

uint8_t const *tud_descriptor_device_cb(void) { return (uint8_t const *)&desc_device; }
uint8_t const *tud_descriptor_configuration_cb(uint8_t index) { (void)index; return desc_config; }

static uint16_t desc_str[33];

uint16_t const *tud_descriptor_string_cb(uint8_t index, uint16_t langid) {
    (void)langid;
    char serial[2 * PICO_UNIQUE_BOARD_ID_SIZE_BYTES + 1];
    const char *s;
    uint8_t n;
    if (index == 0) { desc_str[1] = 0x0409; n = 1; goto done; }
    if (index == 1) s = "contourcap";
    else if (index == 2) s = "contourcap trigger box";
    else if (index == 3) { pico_get_unique_board_id_string(serial, sizeof serial); s = serial; }
    else return NULL;
    n = (uint8_t)strlen(s);
    if (n > 32) n = 32;
    for (uint8_t i = 0; i < n; i++) desc_str[1 + i] = (uint8_t)s[i];
done:
    desc_str[0] = (uint16_t)((TUSB_DESC_STRING << 8) | (2 * n + 2));
    return desc_str;
}

int main(void) {
    gpio_init_mask(OUT_MASK);
    gpio_set_dir_out_masked(OUT_MASK);
    gpio_clr_mask(OUT_MASK);
    tusb_init();
    while (true) tud_task();
}
