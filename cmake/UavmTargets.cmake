# Shared compile settings for every uavmosaic target.
add_library(uavm_warnings INTERFACE)
target_compile_options(uavm_warnings INTERFACE -Wall -Wextra -Wconversion -Wno-sign-conversion)
# No fused multiply-add contraction: aarch64 GCC fuses a*b+c by default, x86-64 cannot without -mfma, and the two
# builds must compute the same mosaic (the cross build is checked against the native one to 0.5 px).
target_compile_options(uavm_warnings INTERFACE -ffp-contract=off)
if(UAVM_WERROR)
  target_compile_options(uavm_warnings INTERFACE -Werror)
endif()
if(UAVM_SANITIZE)
  target_compile_options(uavm_warnings INTERFACE -fsanitize=address,undefined -fno-omit-frame-pointer)
  target_link_options(uavm_warnings INTERFACE -fsanitize=address,undefined)
endif()
if(UAVM_FUZZ)
  # Coverage for libFuzzer in every project target, ASan + UBSan so that memory errors are found, not just crashes;
  # the fuzz/ executables add the libFuzzer driver (-fsanitize=fuzzer).
  target_compile_options(uavm_warnings INTERFACE -fsanitize=fuzzer-no-link,address,undefined
                                                 -fno-sanitize-recover=undefined -fno-omit-frame-pointer)
  target_link_options(uavm_warnings INTERFACE -fsanitize=address,undefined)
endif()

# uavm_library(NAME SOURCES ... DEPS ...): one static library per folder, include root = project root.
function(uavm_library name)
  cmake_parse_arguments(ARG "" "" "SOURCES;DEPS" ${ARGN})
  add_library(${name} STATIC ${ARG_SOURCES})
  target_include_directories(${name} PUBLIC ${PROJECT_SOURCE_DIR})
  target_link_libraries(${name} PUBLIC ${ARG_DEPS} PRIVATE uavm_warnings)
  uavm_use_pch(${name})
endfunction()
