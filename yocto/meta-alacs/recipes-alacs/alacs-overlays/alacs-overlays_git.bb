# nooelint: oelint.var.bbclassextend
# (Boot-partition data for the target only: no native or SDK variant.)
SUMMARY = "ALACS device-tree overlays for the Raspberry Pi (GPIO lines, MCP2515 CAN)"
DESCRIPTION = "alacs-gpio.dtbo names the stepper, laser and limit-switch lines and sets \
               their bias (LASER pulled down); alacs-mcp2515.dtbo adds the MCP2515 SPI \
               CAN controller as can0."
HOMEPAGE = "https://alacs.invalid/"
BUGTRACKER = "https://alacs.invalid/issues"
SECTION = "kernel"
LICENSE = "Apache-2.0"
# The repository has no LICENSE file yet: the common Apache-2.0 text stands in.
# nooelint: oelint.var.licenseremotefile
LIC_FILES_CHKSUM = "file://${COMMON_LICENSE_DIR}/Apache-2.0;md5=89aea4e17d99a7cacdbeed46a0096b10"
CVE_PRODUCT = "alacs-overlays"

DEPENDS = "dtc-native"

PV = "0.1.0+git"

require recipes-alacs/alacs-source.inc

SRC_URI = "${ALACS_GIT_URI};branch=${ALACS_GIT_BRANCH}"
# Built from the commit the layer belongs to (see alacsd_git.bb).
# nooelint: oelint.vars.autorev
SRCREV = "${AUTOREV}"

S = "${WORKDIR}/git"

inherit deploy

# The sources need no preprocessor: the same command as tests/appliance/check.sh.
do_compile() {
    for name in alacs-gpio alacs-mcp2515; do
        dtc -@ -I dts -O dtb -o ${B}/${name}.dtbo ${S}/firmware/dts/${name}-overlay.dts
    done
}

do_install() {
    install -d ${D}${nonarch_base_libdir}/firmware/alacs
    install -m 0644 ${B}/alacs-gpio.dtbo ${B}/alacs-mcp2515.dtbo ${D}${nonarch_base_libdir}/firmware/alacs/
}

# The boot partition takes them from the deploy directory (IMAGE_BOOT_FILES in the kas file).
do_deploy() {
    install -m 0644 ${B}/alacs-gpio.dtbo ${B}/alacs-mcp2515.dtbo ${DEPLOYDIR}/
}
addtask deploy after do_compile before do_build

FILES:${PN} += "${nonarch_base_libdir}/firmware/alacs"
