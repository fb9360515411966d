# Cross-compiling ALACS for 64-bit Arm (Raspberry Pi 4/5) on a Debian 12 host with the
# Debian cross compiler and the arm64 (multiarch) -dev packages:
#   dpkg --add-architecture arm64
#   apt-get install g++-aarch64-linux-gnu qemu-user-static libgpiod-dev:arm64 ...
#   cmake -S . -B build/aarch64 -DCMAKE_TOOLCHAIN_FILE=cmake/toolchain-aarch64.cmake
# tests/aarch64/run.sh installs the packages, builds and runs the unit tests under qemu.
# (The Yocto image does not use this file: bitbake brings its own toolchain file.)
set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR aarch64)

set(CMAKE_C_COMPILER aarch64-linux-gnu-gcc)
set(CMAKE_CXX_COMPILER aarch64-linux-gnu-g++)
# Multiarch: arm64 libraries live in /usr/lib/aarch64-linux-gnu, headers mostly in the
# shared /usr/include, so the host root stays the sysroot and only the library
# directory changes.
set(CMAKE_LIBRARY_ARCHITECTURE aarch64-linux-gnu)

# Never pick up host (amd64) programs' libraries: search the arm64 ones only.
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_IGNORE_PATH /usr/lib/x86_64-linux-gnu /lib/x86_64-linux-gnu
    /usr/lib/x86_64-linux-gnu/cmake /usr/lib/x86_64-linux-gnu/pkgconfig)

# pkg-config must see only the arm64 .pc files (plus the arch-independent ones).
set(ENV{PKG_CONFIG_LIBDIR} "/usr/lib/aarch64-linux-gnu/pkgconfig:/usr/share/pkgconfig")
set(ENV{PKG_CONFIG_PATH} "")

# ctest and Catch2's test discovery run the arm64 binaries through qemu. -L / (not
# /usr/aarch64-linux-gnu): the multiarch loader and libraries are under /, and the other
# prefix made a binary spin at 100 % CPU on this host.
set(CMAKE_CROSSCOMPILING_EMULATOR "qemu-aarch64-static;-L;/")
