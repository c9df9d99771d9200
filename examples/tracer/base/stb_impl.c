/*
 * stb_impl.c - compiles stb_image and stb_image_write into the tracer when the system has
 * only their headers (Debian ships them compiled as libstb, which we link instead).
 */
#define STB_IMAGE_IMPLEMENTATION
#define STB_IMAGE_WRITE_IMPLEMENTATION
#include <stb_image.h>
#include <stb_image_write.h>
