#pragma once
// Small helpers shared by the reconstruction files that call OpenCASCADE (not a public API).

#include <mutex>
#include <string>

#include <Message.hxx>
#include <Message_Messenger.hxx>
#include <Message_PrinterOStream.hxx>
#include <Standard_Failure.hxx>

namespace formloop::recon::occt {

// The data-exchange translators print banners through Message::DefaultMessenger(), whose default
// printer writes to std::cout. formloop keeps stdout for machine-readable output, so the first use
// replaces that printer with one on std::cerr that only passes failures.
inline void KeepStdoutClean() {
  static std::once_flag once;
  std::call_once(once, [] {
    const Handle(Message_Messenger)& messenger = Message::DefaultMessenger();
    messenger->RemovePrinters(STANDARD_TYPE(Message_PrinterOStream));
    messenger->AddPrinter(new Message_PrinterOStream("cerr", Standard_False, Message_Fail));
  });
}

// "Standard_DomainError: message" from an OpenCASCADE exception.
inline std::string Message(const Standard_Failure& failure) {
  const char* text = failure.GetMessageString();
  std::string message = failure.DynamicType()->Name();
  if (text != nullptr && *text != '\0') message += ": " + std::string(text);
  return message;
}

}  // namespace formloop::recon::occt
