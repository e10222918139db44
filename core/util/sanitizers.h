#pragma once
// UAVM_ADDRESS_SANITIZER: 1 in an AddressSanitizer build (GCC's __SANITIZE_ADDRESS__, Clang's
// __has_feature(address_sanitizer)), else 0. Its allocator replaces glibc's: what glibc's malloc does (mallopt, arenas)
// and an allocator of our own that hides blocks from the sanitizer are off there.
#if defined(__SANITIZE_ADDRESS__)
#define UAVM_ADDRESS_SANITIZER 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define UAVM_ADDRESS_SANITIZER 1
#endif
#endif
#ifndef UAVM_ADDRESS_SANITIZER
#define UAVM_ADDRESS_SANITIZER 0
#endif
