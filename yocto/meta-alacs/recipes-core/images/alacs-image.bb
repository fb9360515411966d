# nooelint: oelint.var.suggestedvar.CVE_PRODUCT
# (An image has no CVE product of its own; its packages have.)
SUMMARY = "ALACS sensor appliance image (Raspberry Pi 4/5)"
DESCRIPTION = "A minimal systemd image that boots into alacsd: can0 up at 500 kbit/s \
               through systemd-networkd, the sensor's GPIO lines named by the alacs-gpio \
               overlay, can-utils and the alacs CLI for bring-up."
HOMEPAGE = "https://alacs.invalid/"
BUGTRACKER = "https://alacs.invalid/issues"
SECTION = "images"
LICENSE = "Apache-2.0"

inherit core-image

IMAGE_FEATURES += "ssh-server-dropbear"
IMAGE_LINGUAS = ""

IMAGE_INSTALL = "\
    packagegroup-core-boot \
    packagegroup-alacs \
    can-utils \
    ${CORE_IMAGE_EXTRA_INSTALL} \
"
