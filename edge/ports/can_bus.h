// The CAN bus port (Pigweed's shape: public non-virtual methods state the contract,
// private Do*() virtuals do the work). The protocol node never sees a socket; the sensor
// moves frames between this port and the node. A recording fake is in can_bus_fake.h.
#pragma once

#include "common/clock.h"
#include "common/result.h"
#include "ports/can_port.h"

namespace alacs::ports {

class CanBus {
 public:
  virtual ~CanBus() = default;

  // Sends one frame without blocking. kBusy when the transmit queue is full: the caller
  // keeps the frame and retries later (protocol::CanNode paces the retries); kIo
  // otherwise (for example the interface is down). Event-loop thread only.
  Status send(const CanFrame& frame) { return doSend(frame); }

  // Takes one received frame if one is waiting: Ok(true) and `*frame` filled, Ok(false)
  // when none is. Never blocks. Errors: kIo. Event-loop thread only.
  Result<bool> receive(CanFrame* frame) { return doReceive(frame); }

  // Has the bus send `frame` every `periodNs` by itself (the CANopen heartbeat, timed by
  // the kernel so a busy CPU or a flood cannot delay it); 0 stops it. Call at least every
  // 0.5 s while it should go on: a bus that times the frame itself stops sending when it
  // is no longer refreshed, so a frozen process goes silent. kUnsupported when the bus
  // cannot: the caller then queues the frame itself at each period.
  Status keepCyclic(const CanFrame& frame, TimeNs periodNs, TimeNs now) { return doKeepCyclic(frame, periodNs, now); }
  // Whether keepCyclic() is available (fixed for the bus's lifetime).
  bool hasCyclic() const { return doHasCyclic(); }

 private:
  virtual Status doSend(const CanFrame& frame) = 0;
  virtual Result<bool> doReceive(CanFrame* frame) = 0;

 protected:
  // Defaults for a bus without cyclic transmission (derived buses may fall back to them).
  virtual Status doKeepCyclic(const CanFrame& /*frame*/, TimeNs /*periodNs*/, TimeNs /*now*/) {
    return {Error::kUnsupported, "this CAN bus has no cyclic transmission"};
  }
  virtual bool doHasCyclic() const { return false; }
};

}  // namespace alacs::ports
