# nooelint: oelint.var.bbclassextend
# (A daemon for the target only: no native or SDK variant.)
SUMMARY = "ALACS apple-localization laser sensor daemon"
DESCRIPTION = "alacsd drives the sensor's stepper slide and Class 3R line laser through \
               libgpiod, grabs frames through libcamera, localizes apples and answers over CAN."
HOMEPAGE = "https://alacs.invalid/"
BUGTRACKER = "https://alacs.invalid/issues"
SECTION = "robotics"
LICENSE = "Apache-2.0"
# The repository has no LICENSE file yet: the common Apache-2.0 text stands in.
# nooelint: oelint.var.licenseremotefile
LIC_FILES_CHKSUM = "file://${COMMON_LICENSE_DIR}/Apache-2.0;md5=89aea4e17d99a7cacdbeed46a0096b10"
CVE_PRODUCT = "alacsd"

DEPENDS = "cli11 libeigen libpng nlohmann-json opencv"

PV = "0.1.0+git"

require recipes-alacs/alacs-source.inc

SRC_URI = "${ALACS_GIT_URI};branch=${ALACS_GIT_BRANCH}"
# The layer sits in the project's repository and builds the commit it belongs to; a
# release build pins it: SRCREV:pn-alacsd = "<commit>" (docs/yocto.md).
# nooelint: oelint.vars.autorev
SRCREV = "${AUTOREV}"

S = "${WORKDIR}/git"

inherit cmake pkgconfig systemd useradd

# libgpiod: scarthgap builds 2.1.3, so the driver uses the v2 API (chosen by CMake from the
# pkg-config version). tests: the unit tests need Catch2 v2; scarthgap ships 3.x, so off.
PACKAGECONFIG ??= "libcamera libgpiod systemd"
PACKAGECONFIG[libcamera] = "-DALACS_WITH_LIBCAMERA=ON,-DALACS_WITH_LIBCAMERA=OFF,libcamera"
PACKAGECONFIG[libgpiod] = "-DALACS_WITH_GPIOD=ON,-DALACS_WITH_GPIOD=OFF,libgpiod"
PACKAGECONFIG[systemd] = ",,systemd"
PACKAGECONFIG[tests] = "-DALACS_BUILD_TESTS=ON,-DALACS_BUILD_TESTS=OFF,catch2"
# The board's alacsd has no simulator: no --sim/--replay, alacs_sim not linked.
EXTRA_OECMAKE += "-DALACS_WITH_SIM=OFF"

# The GPIO chip that carries the header lines, by label (alacsd.json gpio.chip); the
# Raspberry Pi 5's kas file sets "pinctrl-rp1".
ALACS_GPIO_CHIP ??= "pinctrl-bcm2711"

do_install:append() {
    install -d ${D}${systemd_system_unitdir}
    install -m 0644 ${S}/firmware/systemd/alacsd.service ${D}${systemd_system_unitdir}/alacsd.service
    install -d ${D}${systemd_unitdir}/network
    install -m 0644 ${S}/firmware/systemd/80-can0.network ${D}${systemd_unitdir}/network/80-can0.network
    install -d ${D}${nonarch_base_libdir}/udev/rules.d
    install -m 0644 ${S}/firmware/udev/60-alacs.rules ${D}${nonarch_base_libdir}/udev/rules.d/60-alacs.rules
    install -d ${D}${sysconfdir}/alacs
    install -m 0644 ${S}/firmware/config/alacsd.json ${D}${sysconfdir}/alacs/alacsd.json
    sed -i -e 's|"chip": "pinctrl-bcm2711"|"chip": "${ALACS_GPIO_CHIP}"|' ${D}${sysconfdir}/alacs/alacsd.json
    install -d ${D}${docdir}/alacs
    install -m 0644 ${S}/docs/install.md ${D}${docdir}/alacs/install.md
}

# DynamicUser=yes in the unit; the udev rule gives /dev/gpiochip* to this group.
USERADD_PACKAGES = "${PN}"
GROUPADD_PARAM:${PN} = "--system gpio"

SYSTEMD_SERVICE:${PN} = "alacsd.service"
SYSTEMD_AUTO_ENABLE:${PN} = "enable"

FILES:${PN} += "${systemd_unitdir}/network ${nonarch_base_libdir}/udev/rules.d"
CONFFILES:${PN} = "${sysconfdir}/alacs/alacsd.json"

# gpioset: the unit's ExecStopPost drives LASER low after any stop.
RDEPENDS:${PN} = "libgpiod-tools"
