/* Minimal ARM semihosting (bkpt 0xAB on M-profile) for the ahrsgen test image.
 * Only what the harness needs: open/read/write/close a host file, write a string to the
 * console, exit with a status.  No newlib stdio, no heap. */
#ifndef AHRSGEN_SEMIHOST_H
#define AHRSGEN_SEMIHOST_H

#include <stddef.h>
#include <stdint.h>

enum { SH_MODE_RB = 1, SH_MODE_WB = 5 };  /* fopen "rb", "wb" */

int32_t sh_open(const char *path, int32_t mode);
int32_t sh_close(int32_t handle);
/* return the number of bytes NOT transferred (semihosting convention); 0 = all */
int32_t sh_write(int32_t handle, const void *buf, size_t len);
int32_t sh_read(int32_t handle, void *buf, size_t len);
void sh_puts(const char *s);
void sh_put_hex(uint32_t v);
__attribute__((noreturn)) void sh_exit(int32_t status);

#endif
