SUMMARY = "ALACS sensor appliance: the daemon and its bring-up tools"
DESCRIPTION = "Everything the sensor box runs: alacsd with its unit, networkd and udev \
               files, the device-tree overlays, CAN and GPIO tools, and the alacs CLI."
HOMEPAGE = "https://alacs.invalid/"
BUGTRACKER = "https://alacs.invalid/issues"
SECTION = "robotics"
LICENSE = "Apache-2.0"

PACKAGE_ARCH = "${MACHINE_ARCH}"

inherit packagegroup

RDEPENDS:${PN} = "\
    alacs-overlays \
    alacsd \
    can-utils \
    iproute2 \
    libcamera \
    libgpiod-tools \
    python3-alacs-cli \
"
