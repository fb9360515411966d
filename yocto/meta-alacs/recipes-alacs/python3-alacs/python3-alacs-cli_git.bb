SUMMARY = "alacs: command-line tool for the ALACS sensor over CAN"
DESCRIPTION = "The alacs CLI (tools/alacs_cli): localize, home, status, monitor and \
               configure an ALACS sensor over any python-can interface."
HOMEPAGE = "https://alacs.invalid/"
BUGTRACKER = "https://alacs.invalid/issues"
SECTION = "devel/python"
LICENSE = "Apache-2.0"
# The repository has no LICENSE file yet: the common Apache-2.0 text stands in.
# nooelint: oelint.var.licenseremotefile
LIC_FILES_CHKSUM = "file://${COMMON_LICENSE_DIR}/Apache-2.0;md5=89aea4e17d99a7cacdbeed46a0096b10"
CVE_PRODUCT = "alacs-cli"

PV = "1.0.0+git"

require recipes-alacs/alacs-source.inc

SRC_URI = "${ALACS_GIT_URI};branch=${ALACS_GIT_BRANCH}"
# Built from the commit the layer belongs to (see alacsd_git.bb).
# nooelint: oelint.vars.autorev
SRCREV = "${AUTOREV}"

S = "${WORKDIR}/git/tools/alacs_cli"

inherit python_setuptools_build_meta

RDEPENDS:${PN} = "python3-alacs-can python3-can python3-cantools"

BBCLASSEXTEND = "native nativesdk"
